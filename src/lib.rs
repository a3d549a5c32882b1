//! nanoforce: vision-based force feedback for nanomanipulation inside an SEM.
//!
//! An AFM cantilever on a Zyvex S100 is tracked in SEM frames; the rotation of its rigid
//! tip gives the slope of the beam's free end, the exact large-deflection elastica turns
//! that slope into a force, and the force is fed back to the operator's haptic device.
//!
//! Modules are cut by domain and layered: each imports only modules listed above it
//! here (docs/architecture.md; `tests/layering.rs` checks it).
//! - [`model`]: the cantilever physics (exact elastica, lookup table, stiffness).
//! - [`checks`]: the validation toolkit every configuration section is checked with.
//! - [`vision`]: the tip tracker, its calibration and its options.
//! - [`hw`]: devices behind small traits, their samples and the real backends.
//! - [`scene`]: synthetic SEM frames with ground truth (tests, benches, simulator).
//! - [`control`]: the teleoperation law and its safety rules.
//! - [`sim`]: the simulated lab (stage, contact, SEM, operator) and its `"sim"` devices.
//! - [`session`]: recorded sessions on disk (frames, SEM metadata, results, scoring).
//! - [`config`]: TOML files -> validated [`config::Config`].
//! - [`report`]: the HTML report about a session, with its plots.
//! - [`daemon`]: the real-time teleoperation daemon, its data stream and monitor page.
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
