//! nanoforce: vision-based force feedback for nanomanipulation inside an SEM.
//!
//! An AFM cantilever on a Zyvex S100 is tracked in SEM frames; the rotation of its rigid
//! tip gives the slope of the beam's free end, the exact large-deflection elastica turns
//! that slope into a force, and the force is fed back to the operator's haptic device.
//!
//! Modules are cut by domain:
//! - [`model`]: the cantilever physics (exact elastica, lookup table, stiffness).
//! - [`scene`]: synthetic SEM frames with ground truth (tests, benches, simulator).
//! - [`vision`]: the tip tracker and its calibration.
//! - [`control`]: the teleoperation law and its safety rules.
//! - [`hw`]: devices behind small traits, each with a simulated backend.
//! - [`sim`]: the simulated lab (stage, contact, SEM, operator).
//! - [`daemon`]: the real-time teleoperation daemon.
//! - [`monitor`]: the daemon's live web page and recorded thumbnails.
//! - [`session`]: recorded sessions on disk (frames, SEM metadata, results, scoring).
//! - [`report`]: the HTML report about a session, with its plots.
//! - [`config`]: TOML files -> validated [`config::Config`].
//! - [`cli`]: the command-line front end over the library.
pub mod checks;
pub mod cli;
pub mod config;
pub mod control;
pub mod daemon;
pub mod hw;
pub mod model;
pub mod report;
pub mod scene;
pub mod session;
pub mod sim;
pub mod vision;
