//! Devices behind small traits, one folder per kind: [`frames::FrameSource`] (the SEM
//! image), [`daq::RateOutput`] (the S100's rate commands through the DAQ) and
//! [`haptic::HapticDevice`] (the operator's stylus), with the samples they give. Real
//! backends sit behind cargo features and [`open`] opens them; each kind's simulated
//! backend lives in the simulated lab (`sim`). The daemon cannot tell them apart.
pub mod clock;
pub mod config;
pub mod daq;
pub mod frames;
pub mod haptic;
pub mod open;
pub mod probe;

pub use clock::Clock;
