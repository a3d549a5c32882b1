//! The real-time teleoperation daemon (`nanoforce run`).
//!
//! Threads, each named, each with one job:
//! - `frames`: the [`FrameSource`](crate::hw::frames::FrameSource) fills a latest-only slot;
//! - `tracker`: the vision tracker turns the newest frame into a published estimate;
//! - `haptic-loop`: the 1 kHz loop (stylus -> law -> force and S100 rate command);
//! - `telemetry`: drains the loops' records into the session folder;
//! - `stream` (when `[stream]` asks for it): the live UDP data stream of estimates and
//!   the haptic state, fed through wait-free rings;
//! - `frame-recorder`: writes the frames the tracker saw into the session's
//!   `frames.nfrm` ([`frame_record`]);
//! - `monitor` (when `[monitor]` asks for it): the live web page and the recorded
//!   thumbnails ([`monitor`]), drawn from [`snapshot`]s the tracker hands over without
//!   waiting;
//! - the supervisor, on a small tokio runtime: signals (SIGHUP reloads the gains;
//!   SIGINT, SIGTERM, SIGQUIT, SIGABRT, SIGUSR1/2, SIGALRM, SIGXCPU stop it), systemd
//!   notifications and watchdog, the status line. Any thread that dies (a panic, in
//!   any of them) stops the run: the haptic loop first, so the outputs are at zero and
//!   forces off before the stop is recorded.
//!
//! [`instance`] keeps one daemon per state directory and device set; [`inject`] lets
//! the tests panic any thread.
//!
//! The blocking loops are plain threads rather than async tasks: a capture call, a
//! tracker pass or a 1 kHz deadline must never wait on an executor, and async is only
//! the wiring around them.
pub mod frame_record;
pub mod haptic_loop;
pub mod inject;
pub mod instance;
pub mod lab;
pub mod monitor;
pub mod notify;
pub mod pipeline;
pub mod rt;
pub mod snapshot;
pub mod stats;
pub mod stream;
mod supervisor;
mod supervisor_health;
pub mod telemetry;

pub use haptic_loop::LoopOptions;
pub use pipeline::Estimator;
pub use supervisor::{
    Daemon, DaemonHandle, Devices, ExitReason, Outcome, Reload, RunOptions, STOP_SIGNALS,
};

use crate::control::SensedForce;
use crate::hw::frames::FrameMeta;

/// What an [`Estimator`] says about one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameEstimate {
    pub detected: bool,
    pub angle_deg: Option<f64>,
    pub force_nn: Option<f64>,
    pub apex_px: Option<[f64; 2]>,
    pub confidence: f64,
    /// The standard error of `angle_deg`, degrees (None: unknown).
    pub angle_sigma_deg: Option<f64>,
}

impl FrameEstimate {
    /// Nothing found.
    pub const NONE: FrameEstimate = FrameEstimate {
        detected: false,
        angle_deg: None,
        force_nn: None,
        apex_px: None,
        confidence: 0.0,
        angle_sigma_deg: None,
    };
}

/// The estimate as published to the haptic loop: plain numbers, NaN where unknown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PublishedEstimate {
    /// 0 = nothing published yet.
    pub seq: u64,
    pub frame_sequence: u64,
    /// Capture time of the frame (daemon clock).
    pub frame_time_s: f64,
    pub published_s: f64,
    /// True only with a finite force: a detection without a force is not a detection
    /// the hand may feel.
    pub detected: bool,
    pub angle_deg: f64,
    pub force_nn: f64,
    pub apex_px: [f64; 2],
    pub confidence: f64,
    /// The standard error of `angle_deg`, degrees; NaN when unknown.
    pub angle_sigma_deg: f64,
}

impl Default for PublishedEstimate {
    fn default() -> Self {
        PublishedEstimate {
            seq: 0,
            frame_sequence: 0,
            frame_time_s: f64::NEG_INFINITY,
            published_s: f64::NEG_INFINITY,
            detected: false,
            angle_deg: f64::NAN,
            force_nn: f64::NAN,
            apex_px: [f64::NAN; 2],
            confidence: 0.0,
            angle_sigma_deg: f64::NAN,
        }
    }
}

impl PublishedEstimate {
    pub fn new(seq: u64, frame: &FrameMeta, published_s: f64, e: &FrameEstimate) -> Self {
        let force_nn = e.force_nn.filter(|f| f.is_finite());
        let detected = e.detected && force_nn.is_some();
        PublishedEstimate {
            seq,
            frame_sequence: frame.sequence,
            frame_time_s: frame.captured_s,
            published_s,
            detected,
            angle_deg: e.angle_deg.filter(|_| detected).unwrap_or(f64::NAN),
            force_nn: force_nn.filter(|_| detected).unwrap_or(f64::NAN),
            apex_px: e.apex_px.filter(|_| detected).unwrap_or([f64::NAN; 2]),
            confidence: e.confidence,
            angle_sigma_deg: e.angle_sigma_deg.filter(|_| detected).unwrap_or(f64::NAN),
        }
    }

    /// The part the teleoperation law uses.
    pub fn sensed(&self) -> SensedForce {
        SensedForce {
            seq: self.seq,
            frame_time_s: self.frame_time_s,
            detected: self.detected,
            force_nn: self.force_nn,
            angle_deg: self.angle_deg,
            angle_sigma_deg: self.angle_sigma_deg,
        }
    }
}
