//! The estimate on its way from the tracker to the operator: the tracker's [`Estimate`]
//! whole, stamped with its frame and when it was published. The haptic loop, the live
//! stream, the monitor and `estimates.csv` all read this one type, and
//! [`Estimate::felt_force_nn`] alone decides what the operator may feel.
use crate::vision::Estimate;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Published {
    /// Increments with every published estimate; 0: nothing published yet.
    pub seq: u64,
    /// The frame's sequence number from its source.
    pub frame_sequence: u64,
    /// When the frame was captured, seconds on the daemon's monotonic clock.
    pub frame_time_s: f64,
    /// When the tracker published it, same clock.
    pub published_s: f64,
    pub estimate: Estimate,
}

impl Default for Published {
    fn default() -> Self {
        Published {
            seq: 0,
            frame_sequence: 0,
            frame_time_s: f64::NEG_INFINITY,
            published_s: f64::NEG_INFINITY,
            estimate: Estimate::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_measured_force_of_a_detection_is_felt() {
        let found = Estimate {
            detected: true,
            angle_deg: Some(0.4),
            force_nn: Some(120.0),
            apex_px: Some([10.0, 20.0]),
            confidence: 0.9,
            ..Estimate::default()
        };
        assert_eq!(found.felt_force_nn(), Some(120.0));
        for (why, e) in [
            (
                "not detected",
                Estimate {
                    detected: false,
                    ..found
                },
            ),
            (
                "no force",
                Estimate {
                    force_nn: None,
                    ..found
                },
            ),
            (
                "not finite",
                Estimate {
                    force_nn: Some(f64::NAN),
                    ..found
                },
            ),
            (
                "clamped",
                Estimate {
                    force_saturated: true,
                    ..found
                },
            ),
        ] {
            assert_eq!(e.felt_force_nn(), None, "{why}");
        }
        assert_eq!(Published::default().estimate.felt_force_nn(), None);
    }
}
