//! Devices behind small traits, one folder per kind: [`frames::FrameSource`] (the SEM
//! image), [`daq::RateOutput`] (the S100's rate commands through the DAQ) and
//! [`haptic::HapticDevice`] (the operator's stylus). Each kind has a simulated backend;
//! real backends sit behind cargo features. The daemon cannot tell them apart.
pub mod clock;
pub mod config;
pub mod daq;
pub mod frames;
pub mod haptic;

pub use clock::Clock;
