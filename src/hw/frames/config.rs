//! `[frames]`: the SEM frame source. `"sim"` (the simulated SEM), `"v4l2"` (a capture
//! card or camera through Video4Linux2) or `"pipe"` (frames written into a FIFO or
//! standard input by another program, e.g. the NI PCI-1410's capture program).
//! Every key is documented in `config/lab.example.toml`.
use std::path::PathBuf;

use serde::Deserialize;

use crate::checks::{Checker, ConfigError, Range};

/// The frame rate asked of the driver: a slow SEM scan (10 s a frame) to a fast camera.
const RATE_HZ: Range = Range::new(0.1, 1000.0, "Hz");
use crate::checks::{in_range, NoKeys};

/// Where frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum FramesBackend {
    Sim,
    V4l2(V4l2Config),
    Pipe(PipeConfig),
}

/// `[frames]` as written: `backend` selects the keys that exist.
#[derive(Debug, Deserialize)]
#[serde(tag = "backend", rename_all = "lowercase")]
pub(crate) enum RawFrames {
    Sim(NoKeys),
    V4l2(RawV4l2),
    Pipe(RawPipe),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawV4l2 {
    device: Option<String>,
    pixel_format: Option<String>,
    width: Option<i64>,
    height: Option<i64>,
    rate_hz: Option<f64>,
    buffers: Option<i64>,
    timeout_ms: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawPipe {
    path: Option<String>,
    format: Option<String>,
    width: Option<i64>,
    height: Option<i64>,
    timeout_ms: Option<i64>,
}

/// How a V4L2 device delivers its pixels; all become 8-bit grey.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit grey, used as is.
    Grey,
    /// YUV 4:2:2 interleaved: the luma bytes are the grey image.
    Yuyv,
    /// Motion JPEG: each frame decoded to luma.
    Mjpeg,
}

impl PixelFormat {
    /// The V4L2 fourcc.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }
}

/// Validated `[frames]` of `backend = "v4l2"`.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Config {
    pub device: PathBuf,
    pub pixel_format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub rate_hz: f64,
    /// Kernel buffers mapped for streaming.
    pub buffers: u32,
    /// No frame for this long: a timeout is reported and the device reopened.
    pub timeout_ms: u64,
}

/// Where a pipe source reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PipePath {
    Stdin,
    /// A FIFO (or a recorded stream file).
    File(PathBuf),
}

/// What a pipe carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PipeFormat {
    /// Each frame behind a 32-byte `NFRM` header (size, sequence, capture time).
    Header,
    /// Bare 8-bit frames of a fixed size, one after the other.
    Raw { width: u32, height: u32 },
}

/// Validated `[frames]` of `backend = "pipe"`.
#[derive(Debug, Clone, PartialEq)]
pub struct PipeConfig {
    pub path: PipePath,
    pub format: PipeFormat,
    pub timeout_ms: u64,
}

impl RawFrames {
    pub(crate) fn validate(self, check: &Checker) -> Result<FramesBackend, ConfigError> {
        Ok(match self {
            RawFrames::Sim(NoKeys {}) => FramesBackend::Sim,
            RawFrames::V4l2(raw) => FramesBackend::V4l2(raw.validate(check)?),
            RawFrames::Pipe(raw) => FramesBackend::Pipe(raw.validate(check)?),
        })
    }
}

/// `frames.width` and `frames.height`, each when given.
fn size(
    check: &Checker,
    width: Option<i64>,
    height: Option<i64>,
) -> Result<(Option<u32>, Option<u32>), ConfigError> {
    let w = width.map(|w| in_range(check, "frames.width", w, (1, 16384), "px"));
    let h = height.map(|h| in_range(check, "frames.height", h, (1, 16384), "px"));
    Ok((w.transpose()?, h.transpose()?))
}

/// `frames.timeout_ms`, `default` when not given.
fn timeout_ms(check: &Checker, value: Option<i64>, default: u64) -> Result<u64, ConfigError> {
    value.map_or(Ok(default), |t| {
        in_range(check, "frames.timeout_ms", t, (10, 600_000), "ms").map(u64::from)
    })
}

impl RawV4l2 {
    fn validate(self, check: &Checker) -> Result<V4l2Config, ConfigError> {
        let pixel_format = match self.pixel_format.as_deref() {
            None | Some("GREY") => PixelFormat::Grey,
            Some("YUYV") => PixelFormat::Yuyv,
            Some("MJPG") | Some("MJPEG") => PixelFormat::Mjpeg,
            Some(other) => {
                return Err(check.invalid(
                    "frames.pixel_format",
                    format_args!("{other:?}"),
                    "must be \"GREY\", \"YUYV\" or \"MJPG\"",
                ))
            }
        };
        let (width, height) = size(check, self.width, self.height)?;
        let rate_hz = check.number_or("frames.rate_hz", self.rate_hz, 30.0, RATE_HZ)?;
        let buffers = self
            .buffers
            .map_or(Ok(4), |b| in_range(check, "frames.buffers", b, (2, 32), ""))?;
        let device = self.device.as_deref().unwrap_or("/dev/video0");
        if device.trim().is_empty() {
            return Err(check.invalid("frames.device", "\"\"", "must name a device"));
        }
        Ok(V4l2Config {
            device: PathBuf::from(device),
            pixel_format,
            width: width.unwrap_or(640),
            height: height.unwrap_or(480),
            rate_hz,
            buffers,
            timeout_ms: timeout_ms(check, self.timeout_ms, 1000)?,
        })
    }
}

impl RawPipe {
    fn validate(self, check: &Checker) -> Result<PipeConfig, ConfigError> {
        let path = match self.path.as_deref() {
            None => {
                return Err(check.inconsistent(
                    "missing frames.path (a FIFO, a stream file, or \"-\" for standard input)"
                        .into(),
                ))
            }
            Some("-") => PipePath::Stdin,
            Some(p) if p.trim().is_empty() => {
                return Err(check.invalid("frames.path", "\"\"", "must name a FIFO or \"-\""))
            }
            Some(p) => PipePath::File(PathBuf::from(p)),
        };
        let size = size(check, self.width, self.height)?;
        let format = match (self.format.as_deref(), size) {
            (None | Some("header"), (None, None)) => PipeFormat::Header,
            (None | Some("header"), _) => {
                return Err(check.inconsistent(
                    "frames.width/height are not used with frames.format = \"header\" \
                     (each frame's header gives its size)"
                        .into(),
                ))
            }
            (Some("raw"), (Some(width), Some(height))) => PipeFormat::Raw { width, height },
            (Some("raw"), _) => {
                return Err(check.inconsistent(
                    "frames.format = \"raw\" needs frames.width and frames.height".into(),
                ))
            }
            (Some(other), _) => {
                return Err(check.invalid(
                    "frames.format",
                    format_args!("{other:?}"),
                    "must be \"header\" or \"raw\"",
                ))
            }
        };
        Ok(PipeConfig {
            path,
            format,
            timeout_ms: timeout_ms(check, self.timeout_ms, 2000)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::config::testing::{error_of, parse};
    use crate::hw::frames::config::*;

    #[test]
    fn v4l2_defaults_and_values() {
        let cfg =
            parse("[frames]\nbackend = \"v4l2\"\npixel_format = \"YUYV\"\nwidth = 320\n").unwrap();
        let FramesBackend::V4l2(v) = cfg.devices.frames else {
            panic!("not v4l2")
        };
        assert_eq!(v.device, PathBuf::from("/dev/video0"));
        assert_eq!(
            (v.pixel_format, v.width, v.height),
            (PixelFormat::Yuyv, 320, 480)
        );
        assert_eq!((v.rate_hz, v.buffers, v.timeout_ms), (30.0, 4, 1000));
    }

    #[test]
    fn pipe_formats() {
        let cfg = parse("[frames]\nbackend = \"pipe\"\npath = \"-\"\n").unwrap();
        assert_eq!(
            cfg.devices.frames,
            FramesBackend::Pipe(PipeConfig {
                path: PipePath::Stdin,
                format: PipeFormat::Header,
                timeout_ms: 2000
            })
        );
        let raw = "[frames]\nbackend = \"pipe\"\npath = \"/run/f\"\nformat = \"raw\"\n";
        let cfg = parse(&format!("{raw}width = 8\nheight = 4\n")).unwrap();
        let FramesBackend::Pipe(p) = cfg.devices.frames else {
            panic!("not pipe")
        };
        assert_eq!(
            p.format,
            PipeFormat::Raw {
                width: 8,
                height: 4
            }
        );
        assert!(error_of(raw).contains("needs frames.width and frames.height"));
    }

    #[test]
    fn frame_errors_name_key_and_value() {
        assert_eq!(
            error_of("[frames]\nbackend = \"v4l2\"\npixel_format = \"RGB3\"\n"),
            "lab.toml: frames.pixel_format must be \"GREY\", \"YUYV\" or \"MJPG\", got \"RGB3\""
        );
        assert_eq!(
            error_of("[frames]\nbackend = \"v4l2\"\nwidth = 0\n"),
            "lab.toml: frames.width = 0 is out of range: accepted 1 to 16384 px"
        );
        assert!(error_of("[frames]\nbackend = \"pipe\"\n").contains("missing frames.path"));
        assert_eq!(
            error_of("[frames]\nbackend = \"pipe\"\npath = \"-\"\ndevice = \"/dev/video0\"\n"),
            "lab.toml: frames.device is not a key of frames.backend = \"pipe\" \
             (its keys: path, format, width, height, timeout_ms)"
        );
    }
}
