//! The simulated lab that stands in for the hardware: the S100 positioner ([`stage`]),
//! the cantilever pressing on a sample ([`contact`], exact elastica), the SEM rendering
//! frames of the bent probe ([`sem`]), and a scripted operator holding the stylus
//! ([`operator`]). The `"sim"` backends wrap these behind `hw`'s device traits:
//! [`daq::SimStage`], [`frames::SimSem`] and [`haptic::SimHaptic`]; [`lab`] builds
//! them from `[sim]`. The daemon cannot tell them from hardware.
pub mod config;
pub mod contact;
pub mod daq;
pub mod frames;
pub mod haptic;
pub mod lab;
pub mod operator;
pub mod sem;
pub mod stage;
