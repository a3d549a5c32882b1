//! The teleoperation law: the PHANToM stylus position commands the S100's velocity (rate
//! control), three soft virtual springs centre the stylus, and the sensed force, scaled,
//! is rendered on top of them, all under the safety rules. Between the estimate and the
//! rendered force stands the plausibility gate ([`Gate`]). Synchronous and
//! allocation-free: the 1 kHz loop thread in `daemon` calls [`Controller::tick`].
mod controller;
mod gains;
mod gate;
mod published;
mod ramp;
mod safety;
mod timing;

pub use controller::{Controller, HapticSample, TickInput, TickOutput};
pub use gains::{GateLimits, SafetyLimits, TeleopGains};
pub(crate) use gains::{RawSafety, RawTeleop};
pub use gate::{Candidate, Gate, GateCounters, Judgement};
pub use published::Published;
pub use ramp::Ramp;
pub use safety::{PressBlock, SafetyCounters, SafetyState};
pub use timing::{FrameTiming, TravelLog};

#[cfg(test)]
mod tests;
