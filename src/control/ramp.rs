//! A continuous ramp: the 60 Hz force estimate becomes a 1 kHz force without steps, and
//! a lost estimate fades to zero, both by moving at a constant rate toward a target.

/// Moves toward a target at a rate chosen when the target is set, so that it arrives
/// after the requested duration. Its value never jumps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    value: f64,
    target: f64,
    rate_per_s: f64,
}

impl Ramp {
    pub const fn new(value: f64) -> Self {
        Ramp {
            value,
            target: value,
            rate_per_s: 0.0,
        }
    }

    /// Head for `target`, arriving `duration_s` from now.
    pub fn retarget(&mut self, target: f64, duration_s: f64) {
        self.target = target;
        self.rate_per_s = (target - self.value).abs() / duration_s.max(1e-6);
    }

    /// Advance by `dt_s` and return the new value.
    pub fn advance(&mut self, dt_s: f64) -> f64 {
        let step = self.rate_per_s * dt_s.max(0.0);
        let remaining = self.target - self.value;
        self.value = if remaining.abs() <= step {
            self.target
        } else {
            self.value + step.copysign(remaining)
        };
        self.value
    }

    pub fn value(&self) -> f64 {
        self.value
    }

    pub fn target(&self) -> f64 {
        self.target
    }

    /// Jump to a value (only for a reset with outputs off).
    pub fn reset(&mut self, value: f64) {
        *self = Ramp::new(value);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arrives_on_time_without_steps() {
        let mut r = Ramp::new(0.0);
        r.retarget(100.0, 0.016);
        let mut prev = 0.0;
        for tick in 1..=20 {
            let v = r.advance(0.001);
            assert!(
                v - prev <= 100.0 / 16.0 + 1e-9,
                "step {} at tick {tick}",
                v - prev
            );
            prev = v;
        }
        assert_eq!(r.value(), 100.0);
    }

    #[test]
    fn retarget_midway_continues_from_current_value() {
        let mut r = Ramp::new(10.0);
        r.retarget(20.0, 0.010);
        for _ in 0..5 {
            r.advance(0.001);
        }
        let mid = r.value();
        assert!((mid - 15.0).abs() < 1e-9);
        r.retarget(0.0, 0.2);
        let next = r.advance(0.001);
        assert!((next - (mid - mid / 200.0)).abs() < 1e-9);
    }

    #[test]
    fn negative_dt_does_nothing() {
        let mut r = Ramp::new(1.0);
        r.retarget(0.0, 0.1);
        assert_eq!(r.advance(-1.0), 1.0);
    }
}
