//! The `"pipe"` frame backend: 8-bit frames written by another program into a FIFO (or
//! our standard input). This is how frames from the NI PCI-1410, which no Linux driver
//! exposes through V4L2, reach the daemon: the vendor's capture program (or a small
//! wrapper around it) writes each frame into the pipe.
//!
//! Protocol (`frames.format = "header"`, the default), all integers little-endian:
//!
//! ```text
//! offset size  field
//!  0      4    magic "NFRM"
//!  4      2    version = 1
//!  6      2    header length in bytes = 32 (readers skip what they do not know)
//!  8      4    width, pixels
//! 12      4    height, pixels
//! 16      8    sequence: the producer's frame counter (a gap = frames it dropped)
//! 24      8    capture time, CLOCK_MONOTONIC nanoseconds (0 = unknown: arrival time)
//! 32   w*h     pixels, 8-bit grey, row-major, no padding
//! ```
//!
//! `frames.format = "raw"` carries bare `width * height` frames of a configured size,
//! numbered on arrival. A FIFO is opened read-write, so the producer may stop and
//! restart without the daemon seeing an end of stream; a header that does not start
//! with the magic is skipped to the next one. Standard input or a file end the stream
//! at EOF. No frame for `timeout_ms` is reported as a timeout.
use std::fs::{File, OpenOptions};
use std::io::Read;
use std::os::fd::{AsRawFd, FromRawFd};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::time::Instant;

use image::GrayImage;

use super::config::{PipeConfig, PipeFormat, PipePath};
use super::{FrameError, FrameMeta, FrameSource, NO_TRUTH};
use crate::hw::Clock;

pub const MAGIC: [u8; 4] = *b"NFRM";
pub const HEADER_LEN: usize = 32;
const MAX_SIDE: u32 = 16384;

/// One frame's header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    pub width: u32,
    pub height: u32,
    pub sequence: u64,
    pub capture_ns: u64,
}

impl FrameHeader {
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut h = [0u8; HEADER_LEN];
        h[0..4].copy_from_slice(&MAGIC);
        h[4..6].copy_from_slice(&1u16.to_le_bytes());
        h[6..8].copy_from_slice(&(HEADER_LEN as u16).to_le_bytes());
        h[8..12].copy_from_slice(&self.width.to_le_bytes());
        h[12..16].copy_from_slice(&self.height.to_le_bytes());
        h[16..24].copy_from_slice(&self.sequence.to_le_bytes());
        h[24..32].copy_from_slice(&self.capture_ns.to_le_bytes());
        h
    }

    /// The header and its declared length, or why it is not one.
    pub fn decode(h: &[u8; HEADER_LEN]) -> Result<(FrameHeader, usize), String> {
        let u32_at = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        let u64_at = |i: usize| u64::from(u32_at(i)) | u64::from(u32_at(i + 4)) << 32;
        if h[0..4] != MAGIC {
            return Err("no NFRM magic".into());
        }
        let len = usize::from(u16::from_le_bytes([h[6], h[7]]));
        let header = FrameHeader {
            width: u32_at(8),
            height: u32_at(12),
            sequence: u64_at(16),
            capture_ns: u64_at(24),
        };
        let sides = [header.width, header.height];
        if len < HEADER_LEN || sides.iter().any(|&s| s == 0 || s > MAX_SIDE) {
            return Err(format!("implausible header {header:?}, length {len}"));
        }
        Ok((header, len))
    }
}

pub struct PipeSource {
    name: String,
    config: PipeConfig,
    file: File,
    clock: Clock,
    skip: Vec<u8>,
    arrivals: u64,
}

fn device_error(name: &str, reason: impl std::fmt::Display) -> FrameError {
    FrameError::Device {
        device: name.into(),
        reason: reason.to_string(),
    }
}

/// Waits until `file` is readable or the deadline passes.
fn wait_readable(
    file: &File,
    name: &str,
    timeout_ms: u64,
    deadline: Instant,
) -> Result<(), FrameError> {
    let left = deadline.saturating_duration_since(Instant::now());
    let mut pfd = libc::pollfd {
        fd: file.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one pollfd we own.
    let n = unsafe { libc::poll(&mut pfd, 1, left.as_millis().min(i32::MAX as u128) as i32) };
    match n {
        0 => Err(FrameError::Timeout {
            device: name.into(),
            timeout_ms,
        }),
        n if n < 0 => {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                Ok(())
            } else {
                Err(device_error(name, e))
            }
        }
        _ => Ok(()),
    }
}

/// Fills `buf` completely, each piece within the deadline; EOF ends the stream.
fn read_exact(
    file: &mut File,
    name: &str,
    timeout_ms: u64,
    buf: &mut [u8],
    deadline: Instant,
) -> Result<(), FrameError> {
    let mut done = 0;
    while done < buf.len() {
        wait_readable(file, name, timeout_ms, deadline)?;
        match file.read(&mut buf[done..]) {
            Ok(0) => {
                return Err(FrameError::EndOfStream {
                    device: name.into(),
                })
            }
            Ok(n) => done += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(device_error(name, e)),
        }
    }
    Ok(())
}

impl PipeSource {
    pub fn open(config: &PipeConfig, clock: Clock) -> Result<PipeSource, FrameError> {
        let (name, file) = match &config.path {
            PipePath::Stdin => {
                // SAFETY: duplicating our standard input gives a descriptor we own.
                let fd = unsafe { libc::dup(0) };
                if fd < 0 {
                    return Err(device_error("pipe:stdin", std::io::Error::last_os_error()));
                }
                // SAFETY: `fd` is a fresh descriptor owned by nobody else.
                ("pipe:stdin".to_string(), unsafe { File::from_raw_fd(fd) })
            }
            PipePath::File(path) => {
                let name = format!("pipe:{}", path.display());
                let meta = std::fs::metadata(path).map_err(|e| {
                    device_error(
                        &name,
                        format!("{e} (create the FIFO with `mkfifo {}`)", path.display()),
                    )
                })?;
                // Read-write on a FIFO: a producer restarting is not an end of stream.
                let fifo = meta.file_type().is_fifo();
                let file = OpenOptions::new()
                    .read(true)
                    .write(fifo)
                    .custom_flags(libc::O_CLOEXEC)
                    .open(path)
                    .map_err(|e| device_error(&name, e))?;
                (name, file)
            }
        };
        Ok(PipeSource {
            name,
            config: config.clone(),
            file,
            clock,
            skip: Vec::new(),
            arrivals: 0,
        })
    }

    fn fill(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), FrameError> {
        read_exact(
            &mut self.file,
            &self.name,
            self.config.timeout_ms,
            buf,
            deadline,
        )
    }

    /// Reads the next valid header, skipping bytes until the magic when out of step.
    fn next_header(&mut self, deadline: Instant) -> Result<FrameHeader, FrameError> {
        let mut header = [0u8; HEADER_LEN];
        self.fill(&mut header, deadline)?;
        let mut skipped = 0usize;
        loop {
            match FrameHeader::decode(&header) {
                Ok((h, len)) => {
                    if skipped > 0 {
                        tracing::warn!(
                            "{}: out of step, skipped {skipped} bytes to the next frame",
                            self.name
                        );
                    }
                    if len > HEADER_LEN {
                        self.skip.resize(len - HEADER_LEN, 0);
                        let mut extra = std::mem::take(&mut self.skip);
                        let result = self.fill(&mut extra, deadline);
                        self.skip = extra;
                        result?;
                    }
                    return Ok(h);
                }
                Err(_) => {
                    header.copy_within(1.., 0);
                    let mut last = [0u8; 1];
                    self.fill(&mut last, deadline)?;
                    header[HEADER_LEN - 1] = last[0];
                    skipped += 1;
                }
            }
        }
    }
}

impl FrameSource for PipeSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        let deadline = Instant::now() + std::time::Duration::from_millis(self.config.timeout_ms);
        let (width, height, sequence, capture_ns) = match self.config.format {
            PipeFormat::Header => {
                let h = self.next_header(deadline)?;
                (h.width, h.height, h.sequence, h.capture_ns)
            }
            PipeFormat::Raw { width, height } => (width, height, self.arrivals + 1, 0),
        };
        if frame.dimensions() != (width, height) {
            *frame = GrayImage::new(width, height);
        }
        self.fill(frame, deadline)?;
        self.arrivals += 1;
        let captured_s = if capture_ns == 0 {
            self.clock.now_s()
        } else {
            self.clock.seconds_at(capture_ns)
        };
        Ok(FrameMeta {
            sequence,
            captured_s,
            truth: NO_TRUTH,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip_and_rejects() {
        let h = FrameHeader {
            width: 640,
            height: 480,
            sequence: 1 << 40 | 7,
            capture_ns: 123_456_789_012,
        };
        let bytes = h.encode();
        assert_eq!(&bytes[0..8], b"NFRM\x01\x00\x20\x00");
        assert_eq!(FrameHeader::decode(&bytes), Ok((h, 32)));
        let mut bad = bytes;
        bad[0] = b'X';
        assert!(FrameHeader::decode(&bad).is_err());
        let mut zero = bytes;
        zero[8..12].copy_from_slice(&0u32.to_le_bytes());
        assert!(FrameHeader::decode(&zero)
            .unwrap_err()
            .contains("implausible"));
    }
}
