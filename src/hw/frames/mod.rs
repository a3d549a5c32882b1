//! SEM frames: a [`FrameSource`] blocks until the next frame, fills a reused grey buffer
//! and says when it was captured (on the daemon's [`Clock`](crate::hw::Clock)).
//! Backends: [`pipe`] (always), `v4l2` (cargo feature `v4l2`) and the simulated SEM
//! (`"sim"`, always; in the `sim` module);
//! [`recording`] reads the frames a session recorded back.
use image::GrayImage;

/// What comes with a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameMeta {
    /// The source's frame counter; a gap means the source itself dropped frames.
    pub sequence: u64,
    /// Capture time on the daemon's clock, seconds.
    pub captured_s: f64,
    /// Ground truth, only from a simulated SEM: one per probe in view, in order.
    pub truth: [Option<FrameTruth>; MAX_TRUTHS],
}

/// Probes a frame carries truth for: an S100 carries up to four positioners, and the
/// tracker follows as many probes in one view (`vision::MAX_PROBES`).
pub const MAX_TRUTHS: usize = 4;

/// A frame without ground truth (from real hardware).
pub const NO_TRUTH: [Option<FrameTruth>; MAX_TRUTHS] = [None; MAX_TRUTHS];

/// What a simulated SEM knows about the frame it rendered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTruth {
    pub probe_in_view: bool,
    pub angle_deg: f64,
    /// The force on the tip; none for a rigid tool (it has no force).
    pub force_nn: Option<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error("{device}: {reason}")]
    Device { device: String, reason: String },
    #[error("{device}: no frame within {timeout_ms} ms")]
    Timeout { device: String, timeout_ms: u64 },
    #[error("{device}: end of stream")]
    EndOfStream { device: String },
}

/// A source of SEM frames (capture card, frame pipe, simulated SEM).
pub trait FrameSource: Send {
    /// A short description for logs, e.g. `v4l2:/dev/video0 640x480 GREY`.
    fn name(&self) -> &str;

    /// Blocks until the next frame, writes it into `frame` (reusing its buffer when the
    /// size is unchanged) and returns its metadata.
    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError>;
}
pub mod config;
pub mod convert;
pub mod pipe;
pub mod recording;
#[cfg(feature = "v4l2")]
pub mod v4l2;
#[cfg(feature = "v4l2")]
pub mod v4l2_sys;
