//! What the haptic loop measures itself, online: the frame source's period and delay
//! (from each estimate's capture time and when the loop first saw it), which judge
//! staleness, and the stage travel it commanded (integrated from its own velocity
//! commands), which bounds the plausible change of the force.

use super::gains::SafetyLimits;

/// The measured frame period follows the intervals smoothly, per frame; two longer
/// intervals in a row are taken at once (the source slowed down: a slow scan is
/// recognised from its third frame, while one late frame barely moves it).
const PERIOD_SMOOTHING: f64 = 0.2;
/// The measured delay follows a larger delay at once and a smaller one slowly, so
/// jitter never makes a steady stream look stale.
const DELAY_RISE: f64 = 1.0;
const DELAY_FALL: f64 = 0.05;

/// The frame source's period and capture-to-arrival delay, measured from estimates.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameTiming {
    last_capture_s: Option<f64>,
    last_interval_s: Option<f64>,
    period_s: Option<f64>,
    delay_s: Option<f64>,
}

impl FrameTiming {
    /// A new estimate of a frame captured at `capture_s`, first seen at `arrival_s`.
    pub fn observe(&mut self, capture_s: f64, arrival_s: f64) {
        if !capture_s.is_finite() {
            return;
        }
        if let Some(last) = self.last_capture_s {
            let interval_s = capture_s - last;
            if interval_s > 0.0 {
                self.period_s = Some(match (self.period_s, self.last_interval_s) {
                    (None, _) => interval_s,
                    // Two long intervals in a row: the source slowed down (a slow scan).
                    (Some(p), Some(last)) if interval_s > p && last > p => interval_s.min(last),
                    (Some(p), _) => p + PERIOD_SMOOTHING * (interval_s - p),
                });
                self.last_interval_s = Some(interval_s);
            }
        }
        self.last_capture_s = Some(capture_s);
        let delay_s = (arrival_s - capture_s).max(0.0);
        self.delay_s = Some(match self.delay_s {
            Some(d) if delay_s > d => d + DELAY_RISE * (delay_s - d),
            Some(d) => d + DELAY_FALL * (delay_s - d),
            None => delay_s,
        });
    }

    /// The measured frame period, once two frames have been seen.
    pub fn period_s(&self) -> Option<f64> {
        self.period_s
    }

    /// The measured capture-to-arrival delay.
    pub fn delay_s(&self) -> Option<f64> {
        self.delay_s
    }

    /// Age (from capture) beyond which an estimate is stale: max(`stale_after_ms`,
    /// margin x period + delay). Before a period is measured, `stale_after_ms` stands
    /// in for it.
    pub fn stale_after_s(&self, limits: &SafetyLimits) -> f64 {
        let floor_s = limits.stale_after_ms * 1e-3;
        let period_s = self.period_s.unwrap_or(floor_s);
        let delay_s = self.delay_s.unwrap_or(0.0);
        floor_s.max(limits.stale_period_margin * period_s + delay_s)
    }

    /// Frames come further apart than `max_frame_period_ms` (a slow scan).
    pub fn too_slow(&self, limits: &SafetyLimits) -> bool {
        self.period_s
            .is_some_and(|p| p * 1e3 > limits.max_frame_period_ms)
    }
}

/// How many ticks of commanded travel are kept (4 s at 1 kHz).
const TRAVEL_LOG_LEN: usize = 4096;

/// The cumulative path length of the commanded stage motion, per tick, for the last few
/// seconds: allocated once, then written in place.
#[derive(Debug, Clone)]
pub struct TravelLog {
    /// (time s, cumulative travel um), a ring.
    samples: Box<[(f64, f64)]>,
    next: usize,
    len: usize,
    total_um: f64,
}

impl Default for TravelLog {
    fn default() -> Self {
        TravelLog {
            samples: vec![(f64::NEG_INFINITY, 0.0); TRAVEL_LOG_LEN].into_boxed_slice(),
            next: 0,
            len: 0,
            total_um: 0.0,
        }
    }
}

impl TravelLog {
    /// The stage was commanded `speed_um_s` for the `dt_s` ending at `now_s`.
    pub fn push(&mut self, now_s: f64, speed_um_s: f64, dt_s: f64) {
        self.total_um += speed_um_s.abs() * dt_s.max(0.0);
        self.samples[self.next] = (now_s, self.total_um);
        self.next = (self.next + 1) % self.samples.len();
        self.len = (self.len + 1).min(self.samples.len());
    }

    /// All commanded travel so far, um.
    pub fn total_um(&self) -> f64 {
        self.total_um
    }

    /// The cumulative travel at `t_s`: the newest sample at or before it, 0 when `t_s`
    /// is older than every sample kept.
    pub fn at(&self, t_s: f64) -> f64 {
        let cap = self.samples.len();
        let nth = |i: usize| self.samples[(self.next + cap - self.len + i) % cap];
        if self.len == 0 || t_s < nth(0).0 {
            // Before the oldest sample kept: count all travel (a larger allowed change).
            return 0.0;
        }
        // Binary search for the last sample with time <= t_s.
        let (mut lo, mut hi) = (0usize, self.len - 1);
        while lo < hi {
            let mid = (lo + hi).div_ceil(2);
            if nth(mid).0 <= t_s {
                lo = mid;
            } else {
                hi = mid - 1;
            }
        }
        nth(lo).1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn period_and_delay_are_measured_and_judge_staleness() {
        let limits = SafetyLimits::default();
        let mut t = FrameTiming::default();
        // Nothing measured: the floor stands in for the period.
        assert!((t.stale_after_s(&limits) - 0.2).abs() < 1e-12);
        // 12 frames per second, 80 ms from capture to arrival.
        for i in 0..30 {
            let capture_s = f64::from(i) / 12.0;
            t.observe(capture_s, capture_s + 0.080);
        }
        assert!((t.period_s().unwrap() - 1.0 / 12.0).abs() < 1e-9);
        assert!((t.delay_s().unwrap() - 0.080).abs() < 1e-9);
        let stale_s = t.stale_after_s(&limits);
        assert!((stale_s - (2.0 / 12.0 + 0.080)).abs() < 1e-9, "{stale_s}");
        // The oldest an estimate gets in this stream is the delay plus one period.
        assert!(stale_s > 0.080 + 1.0 / 12.0 + 0.05);
        assert!(!t.too_slow(&limits));
        // 60 Hz with 20 ms: the configured floor holds.
        let mut fast = FrameTiming::default();
        for i in 0..30 {
            let capture_s = f64::from(i) / 60.0;
            fast.observe(capture_s, capture_s + 0.020);
        }
        assert_eq!(fast.stale_after_s(&limits), 0.1);
    }

    #[test]
    fn a_late_frame_raises_the_delay_at_once_and_it_decays_slowly() {
        let mut t = FrameTiming::default();
        t.observe(0.0, 0.02);
        t.observe(0.1, 0.18);
        assert!((t.delay_s().unwrap() - 0.08).abs() < 1e-12);
        t.observe(0.2, 0.22);
        assert!(t.delay_s().unwrap() > 0.07);
    }

    #[test]
    fn a_slow_scan_is_recognised() {
        let limits = SafetyLimits::default();
        let mut t = FrameTiming::default();
        for i in 0..3 {
            let capture_s = f64::from(i) * 0.6;
            t.observe(capture_s, capture_s + 0.05);
        }
        assert!(t.too_slow(&limits));
    }

    #[test]
    fn travel_log_integrates_and_looks_back() {
        let mut log = TravelLog::default();
        assert_eq!(log.at(1.0), 0.0);
        for i in 1..=1000 {
            let speed = if i <= 500 { 10.0 } else { -20.0 };
            log.push(f64::from(i) * 1e-3, speed, 1e-3);
        }
        assert!((log.total_um() - 15.0).abs() < 1e-9);
        assert!((log.at(0.5) - 5.0).abs() < 1e-9);
        assert!((log.at(0.5004) - 5.0).abs() < 1e-9);
        assert!((log.at(2.0) - 15.0).abs() < 1e-9);
        assert_eq!(log.at(-1.0), 0.0);
        // Wrapped: older than the ring counts from zero travel (all of it allowed).
        for i in 1001..=6000 {
            log.push(f64::from(i) * 1e-3, 1.0, 1e-3);
        }
        assert!((log.at(0.1) - 0.0).abs() < 1e-6, "{}", log.at(0.1));
        assert!((log.at(5.0) - (15.0 + 4.0)).abs() < 1e-6);
    }
}
