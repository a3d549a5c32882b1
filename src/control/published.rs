//! The estimate on its way from the tracker to the operator: the tracker's [`Estimate`]
//! whole, stamped with its frame and when it was published. The haptic loop, the live
//! stream, the monitor and `estimates.csv` all read this one type, and
//! [`Estimate::felt_force_nn`] alone decides what the operator may feel.
use crate::vision::Estimate;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Published {
    /// Which probe of the view it is about: its place in the configuration's probes.
    pub probe: usize,
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
            probe: 0,
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
    fn nothing_published_yet_is_felt_as_nothing() {
        assert_eq!(Published::default().estimate.felt_force_nn(), None);
    }
}
