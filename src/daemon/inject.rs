//! Fault injection for the daemon's tests: a panic in one named thread, some time after
//! the start. Compiled into every build and inert unless asked for: `nanoforce run` reads
//! `NANOFORCE_INJECT_PANIC=<thread>[@<seconds>]` once at start (thread one of
//! [`THREADS`], default delay 0.5 s). The tests use it to check that a panic anywhere
//! leaves the outputs at zero and the stop recorded.
//!
//! The frames, tracker and haptic-loop panics come from wrappers around the devices and
//! the estimator, so they happen inside those threads' own calls; the telemetry, monitor
//! and supervisor threads ask [`PanicInjection::due`] where they loop.
use std::time::{Duration, Instant};

use image::GrayImage;
use nalgebra::Vector3;

use super::Estimator;
use crate::hw::frames::{FrameError, FrameMeta, FrameSource};
use crate::hw::haptic::HapticSample;
use crate::hw::haptic::{HapticDevice, HapticError};
use crate::vision::Estimate;

/// The environment variable `nanoforce run` reads.
pub const ENV: &str = "NANOFORCE_INJECT_PANIC";

/// The threads a panic can be injected into.
pub const THREADS: [&str; 6] = [
    "frames",
    "tracker",
    "haptic-loop",
    "telemetry",
    "monitor",
    "supervisor",
];

/// A panic to inject: in which thread, how long after the start.
#[derive(Debug, Clone, PartialEq)]
pub struct PanicInjection {
    pub thread: &'static str,
    pub after: Duration,
    armed_at: Instant,
}

impl PanicInjection {
    pub fn new(thread: &str, after: Duration) -> Result<Self, String> {
        let thread = THREADS
            .iter()
            .find(|t| **t == thread)
            .ok_or_else(|| format!("{ENV}: unknown thread {thread:?}; one of {THREADS:?}"))?;
        Ok(PanicInjection {
            thread,
            after,
            armed_at: Instant::now(),
        })
    }

    /// `<thread>[@<seconds>]`.
    pub fn parse(spec: &str) -> Result<Self, String> {
        let (thread, after) = match spec.split_once('@') {
            Some((thread, s)) => {
                let secs: f64 = s
                    .parse()
                    .ok()
                    .filter(|s: &f64| s.is_finite() && (0.0..=3600.0).contains(s))
                    .ok_or_else(|| format!("{ENV}: delay {s:?} is not seconds in [0, 3600]"))?;
                (thread, Duration::from_secs_f64(secs))
            }
            None => (spec, Duration::from_millis(500)),
        };
        PanicInjection::new(thread, after)
    }

    /// From the environment; None when the variable is not set.
    pub fn from_env() -> Result<Option<Self>, String> {
        match std::env::var(ENV) {
            Ok(spec) => PanicInjection::parse(&spec).map(Some),
            Err(std::env::VarError::NotPresent) => Ok(None),
            Err(e) => Err(format!("{ENV}: {e}")),
        }
    }

    /// Whether `thread` should panic now.
    pub fn due(&self, thread: &str) -> bool {
        self.thread == thread && self.armed_at.elapsed() >= self.after
    }

    /// Panics if `thread` is due.
    pub fn check(this: Option<&Self>, thread: &str) {
        if this.is_some_and(|i| i.due(thread)) {
            panic!("injected panic in the {thread} thread");
        }
    }
}

/// A frame source that panics in the frames thread when due.
pub struct PanickingFrames {
    pub inner: Box<dyn FrameSource>,
    pub injection: PanicInjection,
}

impl FrameSource for PanickingFrames {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        PanicInjection::check(Some(&self.injection), "frames");
        self.inner.next_frame(frame)
    }
}

/// An estimator that panics in the tracker thread when due.
pub struct PanickingEstimator {
    pub inner: Box<dyn Estimator>,
    pub injection: PanicInjection,
}

impl Estimator for PanickingEstimator {
    fn probes(&self) -> usize {
        self.inner.probes()
    }

    fn estimate(&mut self, frame: &GrayImage, estimates: &mut [Estimate]) {
        PanicInjection::check(Some(&self.injection), "tracker");
        self.inner.estimate(frame, estimates)
    }
}

/// A haptic device whose reads panic in the haptic loop when due (its writes never do:
/// they are what zeroes the outputs while the loop unwinds).
pub struct PanickingHaptic {
    pub inner: Box<dyn HapticDevice>,
    pub injection: PanicInjection,
}

impl HapticDevice for PanickingHaptic {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn has_force_feedback(&self) -> bool {
        self.inner.has_force_feedback()
    }

    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError> {
        PanicInjection::check(Some(&self.injection), "haptic-loop");
        self.inner.read(now_s)
    }

    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError> {
        self.inner.write_force(force_n)
    }

    fn set_forces_enabled(&mut self, enabled: bool) -> Result<(), HapticError> {
        self.inner.set_forces_enabled(enabled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs() {
        let i = PanicInjection::parse("tracker@1.5").unwrap();
        assert_eq!(i.thread, "tracker");
        assert_eq!(i.after, Duration::from_millis(1500));
        assert_eq!(
            PanicInjection::parse("monitor").unwrap().after,
            Duration::from_millis(500)
        );
        assert!(PanicInjection::parse("gpu").unwrap_err().contains("gpu"));
        assert!(PanicInjection::parse("tracker@-1").is_err());
        let now = PanicInjection::parse("telemetry@0").unwrap();
        assert!(now.due("telemetry") && !now.due("tracker"));
    }
}
