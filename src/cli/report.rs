//! `nanoforce report`: one self-contained HTML page (plots embedded) about a replayed or
//! recorded session, plus the plots as PNG files.
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

use crate::report::{write_report, ReportOptions};

/// Write an HTML report (plots, thumbnails, accuracy) about a replayed or recorded session.
#[derive(Debug, Args)]
#[command(
    long_about = "Writes a report about a session: one HTML page that opens in any browser \
with no network (plots embedded), and the plots as PNG files beside it.\n\n\
The page shows force and tip angle over time, detection and confidence over time, a \
histogram of the processing time per frame, a strip of overlay thumbnails (found edges in \
red, blue and green, apex marked) and a summary table: frames, detected, accuracy against \
truth.csv when the session has one (`nanoforce score`'s definitions), and for a recording the \
loop, latency and safety figures of its stats.json.\n\n\
A session of several probes (a configuration with [[probe]] entries) gets a section per \
probe, headed by its name: its summary rows (detected, accuracy against its own \
truth.<name>.csv, a recording's force numbers of the probe in stats.json) and its two \
plots; the processing-time histogram, the thumbnails (every probe drawn), the loop and \
latency figures and the events show once. Its results are read per probe: \
replay.<name>.csv (named from --csv) or estimates.<name>.csv, the names from probe.toml or \
the recording's config.toml.\n\n\
SESSION_DIR is either\n\
- a replayed session: the layout of docs/conventions.md (probe.toml, reference.png, frames/, maybe \
truth.csv) with the CSV of `nanoforce replay` in SESSION_DIR/replay.csv (or --csv); \
thumbnails are drawn from frames/ and the CSV's edge columns; or\n\
- a recording of `nanoforce run` (estimates.csv, stats.json, events.log and, when the run \
drew them, thumbnails/).",
    after_help = "Examples:\n  \
nanoforce replay session/frames --config session/probe.toml --csv session/replay.csv --timing\n  \
nanoforce report session                   # writes session/report/report.html\n  \
nanoforce report ~/.local/state/nanoforce/sessions/20260101T120000Z-4242 --out /tmp/run-report"
)]
pub struct ReportArgs {
    /// The session folder (replayed or recorded).
    #[arg(value_name = "SESSION_DIR")]
    pub session_dir: PathBuf,
    /// Where to write report.html and the PNG files (default: SESSION_DIR/report).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// The replay CSV of a replayed session (default: SESSION_DIR/replay.csv).
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// Most thumbnails in the strip.
    #[arg(long, value_name = "N", default_value_t = 9)]
    pub thumbnails: usize,
}

pub fn run(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let output = write_report(&ReportOptions {
        session_dir: args.session_dir,
        out_dir: args.out,
        csv: args.csv,
        thumbnails: args.thumbnails,
    })?;
    for note in &output.notes {
        tracing::warn!("{note}");
    }
    let detected = super::detected_line(&output.detected);
    eprintln!(
        "report of {} frames ({detected}, {} thumbnails): {}",
        output.frames,
        output.thumbnails,
        output.html.display()
    );
    for png in &output.pngs {
        eprintln!("  {}", png.display());
    }
    Ok(ExitCode::SUCCESS)
}
