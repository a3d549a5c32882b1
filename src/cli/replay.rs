//! `nanoforce replay`: runs the tracker over a recorded session's frames and writes the
//! results CSV (and, on request, Figure-8 style overlays).
use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::config::Config;
use crate::daemon::lab::tracker_from_config;
use crate::session::frames::{list_frames, load_gray};
use crate::session::metadata::{read_sem_metadata, SemMetadata};
use crate::session::results;
use crate::vision::{draw_overlay, Tracker};

/// Track the tip in a recorded session's frames and write the results CSV.
#[derive(Debug, Args)]
#[command(
    long_about = "Tracks the cantilever tip in every frame of a recorded session and \
writes one CSV row per frame.\n\n\
Frames are the PNG, TIFF (8- or 16-bit) and PGM files of FRAMES_DIR, in file-name order. \
A file that does not decode is reported and gets a row with detected = 0; it does not stop \
the replay.\n\n\
CSV columns: frame (file name), detected (1/0), angle_deg (tip rotation from the \
reference, CCW on screen), force_nN (signed as the angle), tip_x, tip_y (the apex, pixels; \
x right, y down) - empty when not detected - then confidence, angle_sigma_deg (the angle's \
standard error from the frame's noise and the calibration's; on rendered frames the errors \
run 1.07-1.14 times it on every look), scale (frame pixels per \
reference pixel), force_saturated, red/blue/green_support (edge pixels), px_per_um, \
magnification, tip_x_um, tip_y_um (from the SEM metadata of TIFF frames: FEI/Thermo tag \
34682 or 34680, Zeiss tag 34118; empty without it, and unreadable metadata is a warning), \
red_x0, red_y0, red_x1, red_y1 and the same for blue and green (the found edge segments, \
pixels), miss (why not detected) and, with --timing, processing_ms. Without --timing the \
CSV is identical from run to run.",
    after_help = "Example:\n  nanoforce replay session/frames --config session/probe.toml --csv out.csv --overlay overlays/\n  \
python3 score.py session/truth.csv out.csv"
)]
pub struct ReplayArgs {
    /// Folder of frames (PNG, TIFF, PGM), replayed in file-name order.
    #[arg(value_name = "FRAMES_DIR")]
    pub frames_dir: PathBuf,
    /// Probe configuration: [cantilever] and [tracker] with its calibration.
    #[arg(long, value_name = "FILE")]
    pub config: PathBuf,
    /// Where to write the results.
    #[arg(long, value_name = "FILE")]
    pub csv: PathBuf,
    /// Also write each frame with the found edges drawn (red, blue, green) and the apex.
    #[arg(long, value_name = "DIR")]
    pub overlay: Option<PathBuf>,
    /// Track every frame from scratch (no search centred on the previous estimate).
    #[arg(long)]
    pub no_coherence: bool,
    /// Add a processing_ms column (makes the CSV differ between runs).
    #[arg(long)]
    pub timing: bool,
}

/// What a replay did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    pub frames: usize,
    pub detected: usize,
    pub unreadable: usize,
    /// Frames whose SEM metadata gave a pixel size.
    pub with_scale: usize,
    /// Frames whose SEM metadata had something wrong with it.
    pub metadata_warnings: usize,
    pub median_ms: Option<f64>,
}

/// Metadata warnings printed in full; later ones are only counted.
const METADATA_WARNINGS_SHOWN: usize = 5;

pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    let config = Config::load(&args.config)?;
    let mut tracker = tracker_from_config(&config)?;
    tracker.set_coherence(!args.no_coherence);
    let summary = replay(&mut tracker, &args)?;
    eprintln!(
        "replayed {} frames: {} detected, {} unreadable, {} with an SEM pixel size{}; median {} ms per frame (tracking)",
        summary.frames,
        summary.detected,
        summary.unreadable,
        summary.with_scale,
        match summary.metadata_warnings {
            0 => String::new(),
            n => format!(" ({n} with metadata warnings)"),
        },
        summary
            .median_ms
            .map_or("-".into(), |ms| format!("{ms:.2}")),
    );
    Ok(ExitCode::SUCCESS)
}

/// Replays the frames of `args.frames_dir` through `tracker` into `args.csv`.
pub fn replay(tracker: &mut Tracker, args: &ReplayArgs) -> anyhow::Result<ReplaySummary> {
    let frames = list_frames(&args.frames_dir)?;
    if let Some(dir) = &args.overlay {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file =
        File::create(&args.csv).with_context(|| format!("creating {}", args.csv.display()))?;
    let mut csv = BufWriter::new(file);
    writeln!(csv, "{}", results::header(args.timing))?;
    let progress = progress_bar(frames.len());
    let mut times_ms = Vec::with_capacity(frames.len());
    let mut summary = ReplaySummary {
        frames: frames.len(),
        detected: 0,
        unreadable: 0,
        with_scale: 0,
        metadata_warnings: 0,
        median_ms: None,
    };
    for path in &frames {
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().to_string());
        let sem = frame_metadata(path, &mut summary, &progress);
        match load_gray(path) {
            Ok(image) => {
                let started = Instant::now();
                let estimate = tracker.track(&image);
                let ms = started.elapsed().as_secs_f64() * 1e3;
                times_ms.push(ms);
                summary.detected += usize::from(estimate.detected);
                let ms_column = args.timing.then_some(ms);
                let written = estimate.with_pixel_origin(tracker.pixel_origin());
                results::write_row(&mut csv, &name, &written, &sem, ms_column)?;
                if let Some(dir) = &args.overlay {
                    write_overlay(dir, path, &draw_overlay(&image, &estimate))?;
                }
            }
            Err(e) => {
                progress.suspend(|| tracing::warn!("{e}; recorded as not detected"));
                summary.unreadable += 1;
                // Coherence must not carry over a gap in the sequence.
                tracker.reset();
                results::write_unreadable(&mut csv, &name, args.timing)?;
            }
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    csv.flush()
        .with_context(|| format!("writing {}", args.csv.display()))?;
    times_ms.sort_by(f64::total_cmp);
    summary.median_ms = times_ms.get(times_ms.len() / 2).copied();
    Ok(summary)
}

/// The SEM metadata of one frame; problems are warned about (the first few in full) and
/// counted.
fn frame_metadata(path: &Path, summary: &mut ReplaySummary, progress: &ProgressBar) -> SemMetadata {
    let sem = read_sem_metadata(path);
    summary.with_scale += usize::from(sem.pixel_size_um.is_some());
    if !sem.warnings.is_empty() {
        summary.metadata_warnings += 1;
        if summary.metadata_warnings <= METADATA_WARNINGS_SHOWN {
            let text = sem.warnings.join("; ");
            progress.suspend(|| tracing::warn!("{}: SEM metadata: {text}", path.display()));
        }
    }
    sem
}

fn write_overlay(dir: &Path, frame: &Path, overlay: &image::RgbImage) -> anyhow::Result<()> {
    let stem = frame
        .file_stem()
        .map_or_else(|| "frame".into(), |s| s.to_string_lossy().to_string());
    let out = dir.join(format!("{stem}.png"));
    overlay
        .save(&out)
        .with_context(|| format!("writing {}", out.display()))
}

fn progress_bar(len: usize) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64);
    if let Ok(style) =
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {elapsed} (eta {eta})")
    {
        bar.set_style(style);
    }
    bar
}
