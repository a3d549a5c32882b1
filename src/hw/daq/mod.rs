//! The S100's rate commands: a [`RateOutput`] turns a stage velocity into the DAQ's
//! outputs. Dropping one must leave the outputs at zero. Backends: `comedi` (cargo
//! feature `comedi`) and the simulated S100 (`"sim"`, always; in the `sim` module).
use nalgebra::Vector3;

#[derive(Debug, thiserror::Error)]
pub enum DaqError {
    #[error("{device}: cannot open: {reason}")]
    Open { device: String, reason: String },
    #[error("{device}: write failed: {reason}")]
    Write { device: String, reason: String },
}

/// Velocity commands to the nanomanipulator, stage frame, micrometres per second.
pub trait RateOutput: Send {
    fn name(&self) -> &str;

    /// Commands a velocity at time `now_s` (daemon clock).
    fn write_velocity(&mut self, now_s: f64, velocity_um_s: Vector3<f64>) -> Result<(), DaqError>;

    /// Sets every output to zero (stop).
    fn zero(&mut self, now_s: f64) -> Result<(), DaqError> {
        self.write_velocity(now_s, Vector3::zeros())
    }
}
#[cfg(feature = "comedi")]
pub mod comedi;
#[cfg(feature = "comedi")]
pub mod comedi_sys;
pub mod config;
