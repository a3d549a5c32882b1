//! `nanoforce replay`: runs the tracker over a recorded session's frames and writes the
//! results CSV (and, on request, Figure-8 style overlays).
//!
//! Outputs never overwrite inputs: before anything is written, the CSV and every overlay
//! path are compared (after resolving symbolic links, `.` and `..`) with the frames, the
//! configuration and its reference image, and an overlay folder that is the frames folder
//! is refused. Overlay names are collision-free: see [`overlay_name`].
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::path::{Component, Path, PathBuf};
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
CSV is identical from run to run.\n\n\
Overlays (--overlay DIR) are PNG files named after their frame: a PNG frame keeps its \
name (frame_00001.png), any other frame gets its full name plus .png (frame_00001.tif \
becomes frame_00001.tif.png), so x.png and x.tif never share an overlay. Outputs never \
overwrite inputs: an overlay folder that is the frames folder, or a CSV or overlay path \
that is a frame, the configuration or its reference image, is refused before anything \
is written.",
    after_help = "Example:\n  nanoforce replay session/frames --config session/probe.toml --csv out.csv --overlay overlays/\n  \
nanoforce score session/truth.csv out.csv"
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
    let reference = config
        .tracker
        .calibration
        .as_ref()
        .map(|c| c.reference_image.as_path());
    let summary = replay(&mut tracker, &args, reference)?;
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

/// Replays the frames of `args.frames_dir` through `tracker` into `args.csv`;
/// `reference` is the configuration's reference image (an input the outputs must spare).
pub fn replay(
    tracker: &mut Tracker,
    args: &ReplayArgs,
    reference: Option<&Path>,
) -> anyhow::Result<ReplaySummary> {
    let frames = list_frames(&args.frames_dir)?;
    let overlay_names = check_outputs(args, &frames, reference)?;
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
    for (path, overlay_name) in frames.iter().zip(&overlay_names) {
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
                    let out = dir.join(overlay_name);
                    draw_overlay(&image, &estimate)
                        .save(&out)
                        .with_context(|| format!("writing {}", out.display()))?;
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

/// The overlay file name of `frame`: a PNG frame keeps its name (`x.png`), any other
/// frame gets its whole name plus `.png` (`x.tif.png`), so frames that differ only in
/// their extension get distinct overlays.
pub fn overlay_name(frame: &Path) -> String {
    let name = frame
        .file_name()
        .map_or_else(|| "frame".into(), |n| n.to_string_lossy().to_string());
    let is_png = frame
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    match frame.file_stem() {
        Some(stem) if is_png => format!("{}.png", stem.to_string_lossy()),
        _ => format!("{name}.png"),
    }
}

/// Refuses outputs that would overwrite an input; returns each frame's overlay name.
fn check_outputs(
    args: &ReplayArgs,
    frames: &[PathBuf],
    reference: Option<&Path>,
) -> anyhow::Result<Vec<String>> {
    let mut inputs: HashMap<PathBuf, String> = HashMap::new();
    for frame in frames {
        inputs.insert(resolved(frame), format!("the frame {}", frame.display()));
    }
    let config = format!("the configuration {}", args.config.display());
    inputs.insert(resolved(&args.config), config);
    if let Some(reference) = reference {
        let what = format!("the reference image {}", reference.display());
        inputs.insert(resolved(reference), what);
    }
    let csv = resolved(&args.csv);
    if let Some(input) = inputs.get(&csv) {
        anyhow::bail!(
            "--csv {} is {input}: refusing to overwrite an input",
            args.csv.display()
        );
    }
    let names: Vec<String> = frames.iter().map(|f| overlay_name(f)).collect();
    let Some(dir) = &args.overlay else {
        return Ok(names);
    };
    let out_dir = resolved(dir);
    if out_dir == resolved(&args.frames_dir) {
        anyhow::bail!(
            "--overlay {} is the frames folder: the overlays would overwrite or join the \
             frames; give another folder",
            dir.display()
        );
    }
    let mut taken: HashMap<&str, &Path> = HashMap::new();
    for (frame, name) in frames.iter().zip(&names) {
        if let Some(other) = taken.insert(name, frame) {
            anyhow::bail!(
                "frames {} and {} would both write the overlay {name}; rename one",
                other.display(),
                frame.display()
            );
        }
        let out = out_dir.join(name);
        if let Some(input) = inputs.get(&out) {
            anyhow::bail!(
                "the overlay of {} would overwrite {input}: refusing; give another \
                 --overlay folder",
                frame.display()
            );
        }
        if out == csv {
            anyhow::bail!(
                "the overlay of {} would overwrite the --csv file {}",
                frame.display(),
                args.csv.display()
            );
        }
    }
    Ok(names)
}

/// `path` made absolute with every symbolic link, `.` and `..` resolved, also when its
/// last components do not exist yet (an output about to be created).
pub(crate) fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for component in absolute.components() {
        match component {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
        if let Ok(real) = out.canonicalize() {
            out = real;
        }
    }
    out
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
