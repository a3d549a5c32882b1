//! The haptic loop's record of one tick, as telemetry (`ticks.csv`) and the live stream
//! read it: a leaf of the daemon, so that the loop can hand it to the stream's tap
//! without the two importing each other.
use crate::control::SafetyState;

/// One telemetry row of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRecord {
    pub t_s: f64,
    pub period_us: f64,
    pub position_mm: [f64; 3],
    pub force_n: [f64; 3],
    pub velocity_um_s: [f64; 3],
    pub rendered_force_nn: f64,
    pub state: SafetyState,
    pub press_blocked: bool,
    /// Estimates the plausibility gate held, and rendered attenuated, so far.
    pub gate_held: u64,
    pub gate_attenuated: u64,
    /// The probe the stylus feels and drives, by its place among the probes.
    pub felt_probe: usize,
}
