//! The command-line front end: one clap subcommand per job, each a thin layer over the
//! library. `src/main.rs` parses [`Cli`] and calls [`run`].
use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod calibrate;
mod model;
pub mod replay;
pub mod run;

/// Vision-based force feedback for nanomanipulation inside a scanning electron microscope.
#[derive(Debug, Parser)]
#[command(
    name = "nanoforce",
    version,
    about = "Vision-based force feedback for nanomanipulation inside an SEM",
    long_about = "nanoforce gives the operator of a Zyvex S100 nanomanipulator a sense of touch.\n\
An AFM cantilever on the S100 is tracked in the SEM frames; the rotation of its rigid tip \
is the slope of the beam's free end, the exact large-deflection elastica turns that slope \
into a force, and the force is fed back to the operator's haptic device.\n\n\
Each job is a subcommand; `nanoforce help SUBCOMMAND` explains it in full.",
    after_help = "Logging: set RUST_LOG (e.g. RUST_LOG=nanoforce=debug) for more detail on standard error."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the real-time teleoperation daemon (default: the built-in simulated lab).
    Run(run::RunArgs),
    /// Track the tip in a recorded session's frames and write the results CSV.
    Replay(replay::ReplayArgs),
    /// Refine clicked tip edges on a reference frame; print the calibration block.
    Calibrate(calibrate::CalibrateArgs),
    Model(model::ModelArgs),
}

/// Runs one subcommand; the exit code says whether it succeeded.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    init_logging();
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Model(args) => model::run(args),
    }
}

/// Human-readable logs on standard error, filtered by RUST_LOG (default: info).
fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // A second initialisation (tests calling `run` twice) is harmless.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
