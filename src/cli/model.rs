//! `nanoforce model`: angles in, exact elastica values out, through the tracker's lookup.
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

/// Tabulate the cantilever model for tip angles read from standard input.
#[derive(Debug, Args)]
#[command(
    long_about = "Reads tip angles in degrees from standard input, one per line, and \
writes CSV to standard output: angle_deg,alpha,delta_over_l,shortening_over_l."
)]
pub struct ModelArgs {
    /// Probe config (TOML with a [cantilever] section): adds a force_nN column.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

pub fn run(_args: ModelArgs) -> anyhow::Result<ExitCode> {
    anyhow::bail!("`model` is not implemented yet")
}
