//! The `"v4l2"` frame backend: a capture card or camera through Video4Linux2, mmap
//! streaming. Each frame carries the kernel's timestamp (CLOCK_MONOTONIC, the daemon's
//! clock, when the driver says so) and its sequence number, so frames the driver
//! dropped show up as gaps. GREY is used as is; YUYV and MJPEG become grey.
//!
//! A device that fails (unplugged, driver error, no frame within `timeout_ms`) is closed
//! and the error reported; the next call reopens it, so the frames thread keeps
//! reporting until the device is back, and then carries on.
use image::GrayImage;

use super::config::{PixelFormat, V4l2Config};
use super::convert::{self, SequenceCounter};
use super::v4l2_sys::{self as sys, Buffer, Device, Mapping};
use super::{FrameError, FrameMeta, FrameSource, NO_TRUTH};
use crate::hw::Clock;

/// An open, streaming device.
struct Stream {
    device: Device,
    buffers: Vec<Mapping>,
    width: u32,
    height: u32,
    bytesperline: usize,
    card: String,
}

impl Drop for Stream {
    fn drop(&mut self) {
        let mut kind = sys::BUF_TYPE_VIDEO_CAPTURE as i32;
        // SAFETY: STREAMOFF takes an int; a failure (device gone) is not actionable.
        let _ = unsafe { self.device.ioctl(sys::VIDIOC_STREAMOFF, &mut kind) };
        // The mappings, then the descriptor, are released by their own drops.
        self.buffers.clear();
    }
}

fn name_of(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

impl Stream {
    fn open(config: &V4l2Config) -> Result<Stream, String> {
        let device = Device::open(&config.device).map_err(|e| format!("cannot open: {e}"))?;
        // SAFETY: every ioctl below gets the argument type its request names.
        let mut cap: sys::Capability = unsafe { std::mem::zeroed() };
        unsafe { device.ioctl(sys::VIDIOC_QUERYCAP, &mut cap) }
            .map_err(|e| format!("not a V4L2 device (VIDIOC_QUERYCAP: {e})"))?;
        let caps = if cap.capabilities & sys::CAP_DEVICE_CAPS != 0 {
            cap.device_caps
        } else {
            cap.capabilities
        };
        if caps & sys::CAP_VIDEO_CAPTURE == 0 || caps & sys::CAP_STREAMING == 0 {
            return Err(format!(
                "{} is not a streaming capture device",
                name_of(&cap.card)
            ));
        }
        let wanted = sys::fourcc(config.pixel_format.fourcc());
        let mut format = sys::Format {
            kind: sys::BUF_TYPE_VIDEO_CAPTURE,
            fmt: sys::FormatUnion { raw: [0; 200] },
        };
        format.fmt.pix = sys::PixFormat {
            width: config.width,
            height: config.height,
            pixelformat: wanted,
            field: sys::FIELD_ANY,
            ..Default::default()
        };
        unsafe { device.ioctl(sys::VIDIOC_S_FMT, &mut format) }
            .map_err(|e| format!("VIDIOC_S_FMT: {e}"))?;
        // SAFETY: S_FMT filled the pix member for a capture buffer type.
        let pix = unsafe { format.fmt.pix };
        if pix.pixelformat != wanted {
            let got = String::from_utf8_lossy(&pix.pixelformat.to_le_bytes()).into_owned();
            return Err(format!(
                "does not offer {:?} frames (it chose {got:?})",
                config.pixel_format
            ));
        }
        if (pix.width, pix.height) != (config.width, config.height) {
            tracing::warn!(
                "{}: asked for {}x{}, the driver gives {}x{}",
                config.device.display(),
                config.width,
                config.height,
                pix.width,
                pix.height
            );
        }
        let mut parm = sys::StreamParm {
            kind: sys::BUF_TYPE_VIDEO_CAPTURE,
            parm: sys::ParmUnion { raw: [0; 200] },
        };
        parm.parm.capture = sys::CaptureParm {
            timeperframe: [1000, (config.rate_hz * 1000.0).round() as u32],
            ..Default::default()
        };
        if let Err(e) = unsafe { device.ioctl(sys::VIDIOC_S_PARM, &mut parm) } {
            tracing::warn!(
                "{}: cannot set the frame rate ({e}); using the driver's",
                config.device.display()
            );
        }
        let mut request = sys::RequestBuffers {
            count: config.buffers,
            kind: sys::BUF_TYPE_VIDEO_CAPTURE,
            memory: sys::MEMORY_MMAP,
            ..Default::default()
        };
        unsafe { device.ioctl(sys::VIDIOC_REQBUFS, &mut request) }
            .map_err(|e| format!("VIDIOC_REQBUFS: {e}"))?;
        if request.count < 2 {
            return Err(format!("only {} capture buffer(s)", request.count));
        }
        let mut stream = Stream {
            device,
            buffers: Vec::with_capacity(request.count as usize),
            width: pix.width,
            height: pix.height,
            bytesperline: pix.bytesperline as usize,
            card: name_of(&cap.card),
        };
        for index in 0..request.count {
            let mut buffer = Buffer {
                index,
                ..stream.blank()
            };
            unsafe { stream.device.ioctl(sys::VIDIOC_QUERYBUF, &mut buffer) }
                .map_err(|e| format!("VIDIOC_QUERYBUF: {e}"))?;
            stream.buffers.push(
                stream
                    .device
                    .map(&buffer)
                    .map_err(|e| format!("mmap: {e}"))?,
            );
            unsafe { stream.device.ioctl(sys::VIDIOC_QBUF, &mut buffer) }
                .map_err(|e| format!("VIDIOC_QBUF: {e}"))?;
        }
        let mut kind = sys::BUF_TYPE_VIDEO_CAPTURE as i32;
        unsafe { stream.device.ioctl(sys::VIDIOC_STREAMON, &mut kind) }
            .map_err(|e| format!("VIDIOC_STREAMON: {e}"))?;
        Ok(stream)
    }

    fn blank(&self) -> Buffer {
        Buffer {
            kind: sys::BUF_TYPE_VIDEO_CAPTURE,
            memory: sys::MEMORY_MMAP,
            ..Default::default()
        }
    }
}

pub struct V4l2Source {
    name: String,
    config: V4l2Config,
    clock: Clock,
    stream: Option<Stream>,
    sequence: SequenceCounter,
    period_s: f64,
}

impl V4l2Source {
    /// Opens and starts the device; an error names the device and why.
    pub fn open(config: &V4l2Config, clock: Clock) -> Result<V4l2Source, FrameError> {
        let name = format!(
            "v4l2:{} {}x{} {:?}",
            config.device.display(),
            config.width,
            config.height,
            config.pixel_format
        );
        let stream = Stream::open(config).map_err(|reason| FrameError::Device {
            device: name.clone(),
            reason,
        })?;
        tracing::info!(
            "{name}: streaming from {} ({}x{})",
            stream.card,
            stream.width,
            stream.height
        );
        Ok(V4l2Source {
            name,
            config: config.clone(),
            clock,
            stream: Some(stream),
            sequence: SequenceCounter::default(),
            period_s: 1.0 / config.rate_hz,
        })
    }

    fn error(&self, reason: String) -> FrameError {
        FrameError::Device {
            device: self.name.clone(),
            reason,
        }
    }

    /// Closes the device after a failure; the next frame request reopens it.
    fn lose(&mut self, reason: String) -> FrameError {
        self.stream = None;
        self.sequence.restart();
        tracing::warn!("{}: {reason}; closing it, will reopen", self.name);
        self.error(format!("{reason}; reopening"))
    }
}

impl FrameSource for V4l2Source {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        if self.stream.is_none() {
            let stream =
                Stream::open(&self.config).map_err(|e| self.error(format!("reopening: {e}")))?;
            tracing::info!("{}: reopened", self.name);
            self.stream = Some(stream);
        }
        let timeout_ms = self.config.timeout_ms;
        loop {
            let Some(stream) = &self.stream else {
                return Err(self.error("the device is not open".into()));
            };
            match stream.device.poll(timeout_ms.min(i32::MAX as u64) as i32) {
                Ok(true) => {}
                Ok(false) => {
                    self.lose(format!("no frame within {timeout_ms} ms"));
                    return Err(FrameError::Timeout {
                        device: self.name.clone(),
                        timeout_ms,
                    });
                }
                Err(e) => return Err(self.lose(format!("device lost ({e})"))),
            }
            let mut buffer = stream.blank();
            // SAFETY: DQBUF takes a v4l2_buffer.
            if let Err(e) = unsafe { stream.device.ioctl(sys::VIDIOC_DQBUF, &mut buffer) } {
                if e.kind() == std::io::ErrorKind::WouldBlock {
                    continue;
                }
                return Err(self.lose(format!("device lost (VIDIOC_DQBUF: {e})")));
            }
            let arrived_s = self.clock.now_s();
            let converted = match self
                .stream
                .as_ref()
                .and_then(|s| s.buffers.get(buffer.index as usize))
            {
                _ if buffer.flags & sys::BUF_FLAG_ERROR != 0 => {
                    Err("the driver flagged the frame as corrupt".into())
                }
                Some(mapping) => {
                    let bytes = mapping.bytes(buffer.bytesused as usize);
                    let (w, h, bpl) = (stream.width, stream.height, stream.bytesperline);
                    match self.config.pixel_format {
                        PixelFormat::Grey => {
                            convert::grey_into(bytes, w, h, bpl.max(w as usize), frame)
                        }
                        PixelFormat::Yuyv => {
                            convert::yuyv_into(bytes, w, h, bpl.max(2 * w as usize), frame)
                        }
                        PixelFormat::Mjpeg => convert::mjpeg_into(bytes, frame),
                    }
                }
                None => Err(format!("buffer index {} out of range", buffer.index)),
            };
            let Some(stream) = &self.stream else {
                return Err(self.error("the device is not open".into()));
            };
            // SAFETY: QBUF takes the v4l2_buffer DQBUF gave us.
            if let Err(e) = unsafe { stream.device.ioctl(sys::VIDIOC_QBUF, &mut buffer) } {
                return Err(self.lose(format!("device lost (VIDIOC_QBUF: {e})")));
            }
            if let Err(reason) = converted {
                return Err(self.error(reason));
            }
            let monotonic =
                buffer.flags & sys::BUF_FLAG_TIMESTAMP_MASK == sys::BUF_FLAG_TIMESTAMP_MONOTONIC;
            let captured_s = if monotonic {
                let ns = buffer.timestamp.tv_sec as u64 * 1_000_000_000
                    + buffer.timestamp.tv_usec as u64 * 1000;
                self.clock.seconds_at(ns)
            } else {
                arrived_s
            };
            let sequence = self
                .sequence
                .next(buffer.sequence, captured_s, self.period_s);
            return Ok(FrameMeta {
                sequence,
                captured_s,
                truth: NO_TRUTH,
            });
        }
    }
}
