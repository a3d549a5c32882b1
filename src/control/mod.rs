//! The teleoperation law: the PHANToM stylus position commands the S100's velocity (rate
//! control), three soft virtual springs centre the stylus, and the sensed force, scaled,
//! is rendered on top of them, all under the safety rules. Synchronous and
//! allocation-free: the 1 kHz loop thread in `daemon` calls [`Controller::tick`].
mod controller;
mod gains;
mod ramp;
mod safety;

pub use controller::{Controller, HapticSample, SensedForce, TickInput, TickOutput};
pub(crate) use gains::{RawSafety, RawTeleop};
pub use gains::{SafetyLimits, TeleopGains};
pub use ramp::Ramp;
pub use safety::{PressBlock, SafetyCounters, SafetyState};

#[cfg(test)]
mod tests;
