//! The command-line front end: one clap subcommand per job, each a thin layer over the
//! library. `src/main.rs` parses [`Cli`] and calls [`run()`].
//!
//! Its doc comments are the command-line help (clap): `[section]` there names a TOML
//! section of the configuration, and `<name>` a placeholder, not an item or a tag.
#![allow(rustdoc::broken_intra_doc_links, rustdoc::invalid_html_tags)]
use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod calibrate;
pub mod logging;
mod model;
pub mod probe_devices;
pub mod replay;
mod replay_pool;
pub mod report;
pub mod run;
pub mod score;

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

/// No doc comments here: each subcommand's one-line summary is the doc comment of its
/// arguments struct, beside its `long_about`. A doc comment on a variant would replace
/// both, and `nanoforce replay --help` would lose its description of the CSV columns.
#[derive(Debug, Subcommand)]
pub enum Command {
    Run(run::RunArgs),
    Replay(replay::ReplayArgs),
    Calibrate(calibrate::CalibrateArgs),
    Report(report::ReportArgs),
    Score(score::ScoreArgs),
    Model(model::ModelArgs),
    ProbeDevices(probe_devices::ProbeArgs),
}

/// Runs one subcommand; the exit code says whether it succeeded.
/// Each probe's detections as replay and report print them: `12 detected` for a lone
/// probe, `left 12 detected, right 11 detected` for several.
fn detected_line<N: std::fmt::Display>(detected: &[(N, usize)]) -> String {
    match detected {
        [(_, n)] => format!("{n} detected"),
        several => several
            .iter()
            .map(|(name, n)| format!("{name} {n} detected"))
            .collect::<Vec<_>>()
            .join(", "),
    }
}

pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    logging::init();
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Report(args) => report::run(args),
        Command::Score(args) => score::run(args),
        Command::Model(args) => model::run(args),
        Command::ProbeDevices(args) => probe_devices::run(args),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn every_subcommand_has_a_summary_and_its_long_help() {
        let cli = Cli::command();
        for sub in cli.get_subcommands() {
            let name = sub.get_name();
            let about = sub.get_about().map(|a| a.to_string()).unwrap_or_default();
            let long = sub
                .get_long_about()
                .map(|a| a.to_string())
                .unwrap_or_default();
            assert!(!about.is_empty(), "{name}: no summary");
            assert!(
                long.len() > about.len() + 40,
                "{name}: no long help ({long:?})"
            );
        }
        let replay = cli.find_subcommand("replay").unwrap();
        let long = replay.get_long_about().unwrap().to_string();
        assert!(long.contains("CSV columns") && long.contains("angle_sigma_deg"));
        let score = cli.find_subcommand("score").unwrap();
        let long = score.get_long_about().unwrap().to_string();
        assert!(long.contains("false_detections") && long.contains("force_err_"));
        let args: Vec<String> = score
            .get_positionals()
            .map(|a| a.get_id().to_string())
            .collect();
        assert_eq!(args, ["truth", "result"]);
    }
}
