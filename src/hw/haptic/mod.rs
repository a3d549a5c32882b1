//! The operator's stylus: a [`HapticDevice`] gives position and velocity and takes a
//! force, in its own frame (millimetres, newtons). Backends: `openhaptics`
//! (cargo feature `openhaptics`), `hid` (cargo feature `hidapi`) and the scripted
//! operator's stylus (`"sim"`, always; in the `sim` module).
use nalgebra::Vector3;

/// The stylus as read this tick (haptic frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HapticSample {
    pub position_mm: Vector3<f64>,
    pub velocity_mm_s: Vector3<f64>,
    /// The stylus buttons held down, one bit each: bit 0 the first (front) button,
    /// bit 1 the second. [`SWITCH_BUTTON`] moves the stylus to the next felt probe.
    pub buttons: u32,
}

/// The button (its bit in [`HapticSample::buttons`]) that switches the stylus to the
/// next probe it feels: the PHANToM's second button, or on a `hid` device the button at
/// `switch_button_bit`. Pressing it stops motion until the stylus is back at the centre
/// (the deadman re-engage), then the stylus drives and feels the next probe.
pub const SWITCH_BUTTON: u32 = 1 << 1;

#[derive(Debug, thiserror::Error)]
pub enum HapticError {
    #[error("{device}: cannot open: {reason}")]
    Open { device: String, reason: String },
    #[error("{device}: device lost: {reason}")]
    Lost { device: String, reason: String },
    #[error("{device}: {reason}")]
    Device { device: String, reason: String },
}

pub trait HapticDevice: Send {
    fn name(&self) -> &str;

    /// Whether forces can be rendered (a plain joystick cannot).
    fn has_force_feedback(&self) -> bool {
        true
    }

    /// The stylus now (`now_s` on the daemon clock, for devices that need it).
    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError>;

    /// The force to render until the next call.
    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError>;

    /// Turns force output on or off; off must leave the stylus free.
    fn set_forces_enabled(&mut self, enabled: bool) -> Result<(), HapticError>;
}
pub mod config;
#[cfg(feature = "openhaptics")]
pub mod hd_sys;
#[cfg(feature = "hidapi")]
pub mod hid;
pub mod hid_report;
#[cfg(feature = "hidapi")]
pub mod hidapi_sys;
#[cfg(feature = "openhaptics")]
pub mod openhaptics;
