//! The simulated lab that stands in for the hardware: the S100 positioner ([`stage`]),
//! the cantilever pressing on a sample ([`contact`], exact elastica), the SEM rendering
//! frames of the bent probe, and a scripted operator holding the stylus ([`operator`]).
//! The `"sim"` backends in `hw` wrap these; the daemon cannot tell them from hardware.
pub mod config;
pub mod contact;
pub mod operator;
pub mod sem;
pub mod stage;
