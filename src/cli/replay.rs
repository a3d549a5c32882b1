//! `nanoforce replay`: runs the tracker over a recorded session's frames and writes the
//! results CSV (and, on request, Figure-8 style overlays). The frames are a folder of
//! image files, or the `frames.nfrm` of a session `nanoforce run` recorded (tracked with
//! the configuration the run used, unless `--config` gives another).
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

use image::GrayImage;

use crate::config::Config;
use crate::daemon::lab::{live_tracker, tracker_from_config};
use crate::hw::frames::recording::FrameFile;
use crate::session::frames::{list_frames, load_gray};
use crate::session::live::{is_live_session, SessionInfo, CONFIG_FILE, SESSION_FILE};
use crate::session::metadata::{read_sem_metadata, SemMetadata};
use crate::session::results::{self, FrameLabel};
use crate::vision::{draw_overlay, Tracker};

/// Track the tip in a recorded session's frames and write the results CSV.
#[derive(Debug, Args)]
#[command(
    long_about = "Tracks the cantilever tip in every frame of a recorded session and \
writes one CSV row per frame.\n\n\
A session folder recorded by `nanoforce run` (it holds session.json and frames.nfrm) is \
tracked again frame by frame, with the configuration the run used (its config.toml) or, \
after re-calibrating, the one --config names. Its rows carry the frame's sequence number \
(frame_seq, as in the session's estimates.csv) and capture time (utc).\n\n\
Any other folder is a folder of frames: the PNG, TIFF (8- or 16-bit) and PGM files of \
FRAMES_DIR, in file-name order (frame_seq counts them 1, 2, ...); --config is required. \
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
pixels), miss (why not detected), frame_seq, utc and, with --timing, processing_ms. \
Without --timing the \
CSV is identical from run to run.\n\n\
Overlays (--overlay DIR) are PNG files named after their frame: a PNG frame keeps its \
name (frame_00001.png), any other frame gets its full name plus .png (frame_00001.tif \
becomes frame_00001.tif.png), so x.png and x.tif never share an overlay. Outputs never \
overwrite inputs: an overlay folder that is the frames folder, or a CSV or overlay path \
that is a frame, the configuration or its reference image, is refused before anything \
is written.",
    after_help = "Examples:\n  nanoforce replay session/frames --config session/probe.toml --csv out.csv --overlay overlays/\n  \
python3 score.py session/truth.csv out.csv\n  \
nanoforce replay /var/lib/nanoforce/sessions/20261203T000108Z-4242 --csv again.csv"
)]
pub struct ReplayArgs {
    /// A session folder recorded by `nanoforce run`, or a folder of frames (PNG, TIFF,
    /// PGM) replayed in file-name order.
    #[arg(value_name = "SESSION_OR_FRAMES_DIR")]
    pub frames_dir: PathBuf,
    /// Probe configuration: [cantilever] and [tracker] with its calibration (default for
    /// a recorded session: the configuration it ran with).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
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
    let session = is_live_session(&args.frames_dir)
        .then(|| SessionInfo::read(&args.frames_dir))
        .transpose()?;
    let (config, config_path) = load_config(&args, session.as_ref())?;
    let mut tracker = match session {
        Some(_) => live_tracker(&config)?,
        None => tracker_from_config(&config)?,
    };
    tracker.set_coherence(!args.no_coherence);
    let inputs = Inputs {
        config: &config_path,
        reference: config
            .tracker
            .calibration
            .as_ref()
            .map(|c| c.reference_image.as_path()),
    };
    let summary = match &session {
        Some(info) => replay_session(&mut tracker, &args, info, &inputs)?,
        None => replay(&mut tracker, &args, &inputs)?,
    };
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

/// The configuration (--config, or the one a recorded session ran with) and its path.
fn load_config(
    args: &ReplayArgs,
    session: Option<&SessionInfo>,
) -> anyhow::Result<(Config, PathBuf)> {
    match (&args.config, session) {
        (Some(path), _) => Ok((Config::load(path)?, path.clone())),
        (None, Some(info)) => {
            let path = args.frames_dir.join(CONFIG_FILE);
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            // Relative paths (the reference image) resolve as in the run: next to the
            // file it loaded.
            let base = info
                .config_file
                .as_ref()
                .map_or(path.clone(), PathBuf::from);
            let config = Config::from_toml_str(&text, &base)
                .with_context(|| format!("the configuration of the session, {}", path.display()))?;
            Ok((config, path))
        }
        (None, None) => anyhow::bail!(
            "{}: not a session recorded by `nanoforce run` (no {SESSION_FILE}): a folder \
             of frames needs --config",
            args.frames_dir.display()
        ),
    }
}

/// The files a replay reads besides the frames, which its outputs must spare.
pub struct Inputs<'a> {
    pub config: &'a Path,
    /// The configuration's reference image.
    pub reference: Option<&'a Path>,
}

/// The results CSV, overlays and timing of a replay as it goes.
struct Output<'a> {
    args: &'a ReplayArgs,
    csv: BufWriter<File>,
    progress: ProgressBar,
    times_ms: Vec<f64>,
    summary: ReplaySummary,
}

impl<'a> Output<'a> {
    fn create(args: &'a ReplayArgs, frames: Option<usize>) -> anyhow::Result<Output<'a>> {
        if let Some(dir) = &args.overlay {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let file =
            File::create(&args.csv).with_context(|| format!("creating {}", args.csv.display()))?;
        let mut csv = BufWriter::new(file);
        writeln!(csv, "{}", results::header(args.timing))?;
        Ok(Output {
            args,
            csv,
            progress: progress_bar(frames),
            times_ms: Vec::with_capacity(frames.unwrap_or(0)),
            summary: ReplaySummary {
                frames: 0,
                detected: 0,
                unreadable: 0,
                with_scale: 0,
                metadata_warnings: 0,
                median_ms: None,
            },
        })
    }

    /// Tracks one frame and writes its row (and overlay, named `overlay_name`).
    fn track(
        &mut self,
        tracker: &mut Tracker,
        image: &GrayImage,
        label: &FrameLabel,
        sem: &SemMetadata,
        overlay_name: &str,
    ) -> anyhow::Result<()> {
        let started = Instant::now();
        let estimate = tracker.track(image);
        let ms = started.elapsed().as_secs_f64() * 1e3;
        self.times_ms.push(ms);
        self.summary.frames += 1;
        self.summary.detected += usize::from(estimate.detected);
        let ms_column = self.args.timing.then_some(ms);
        let written = estimate.with_pixel_origin(tracker.pixel_origin());
        results::write_row(&mut self.csv, label, &written, sem, ms_column)?;
        if let Some(dir) = &self.args.overlay {
            let out = dir.join(overlay_name);
            draw_overlay(image, &estimate)
                .save(&out)
                .with_context(|| format!("writing {}", out.display()))?;
        }
        self.progress.inc(1);
        Ok(())
    }

    fn finish(mut self) -> anyhow::Result<ReplaySummary> {
        self.progress.finish_and_clear();
        self.csv
            .flush()
            .with_context(|| format!("writing {}", self.args.csv.display()))?;
        self.times_ms.sort_by(f64::total_cmp);
        self.summary.median_ms = self.times_ms.get(self.times_ms.len() / 2).copied();
        Ok(self.summary)
    }
}

/// Replays the frames of `args.frames_dir` through `tracker` into `args.csv`.
pub fn replay(
    tracker: &mut Tracker,
    args: &ReplayArgs,
    inputs: &Inputs,
) -> anyhow::Result<ReplaySummary> {
    let frames = list_frames(&args.frames_dir)?;
    let overlay_names = check_outputs(args, &frames, inputs)?;
    let mut out = Output::create(args, Some(frames.len()))?;
    for (index, (path, overlay_name)) in frames.iter().zip(&overlay_names).enumerate() {
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().to_string());
        let label = FrameLabel {
            name: &name,
            seq: index as u64 + 1,
            utc: "",
        };
        let sem = frame_metadata(path, &mut out.summary, &out.progress);
        match load_gray(path) {
            Ok(image) => out.track(tracker, &image, &label, &sem, overlay_name)?,
            Err(e) => {
                out.progress
                    .suspend(|| tracing::warn!("{e}; recorded as not detected"));
                out.summary.frames += 1;
                out.summary.unreadable += 1;
                // Coherence must not carry over a gap in the sequence.
                tracker.reset();
                results::write_unreadable(&mut out.csv, &label, args.timing)?;
                out.progress.inc(1);
            }
        }
    }
    out.finish()
}

/// Replays a session recorded by `nanoforce run` (its `frames.nfrm`, in recorded order)
/// through `tracker` into `args.csv`. Frames the recording dropped leave a gap in
/// `frame_seq`; the tracker goes on across it, as the live tracker did across the frames
/// it never saw.
pub fn replay_session(
    tracker: &mut Tracker,
    args: &ReplayArgs,
    info: &SessionInfo,
    inputs: &Inputs,
) -> anyhow::Result<ReplaySummary> {
    let session_json = args.frames_dir.join(SESSION_FILE);
    let Some(frames_path) = info.frames_path(&args.frames_dir) else {
        anyhow::bail!(
            "{}: this session recorded no frames (no frames_file)",
            session_json.display()
        );
    };
    check_outputs(args, &[frames_path.clone(), session_json], inputs)?;
    let mut frames = FrameFile::open(&frames_path)?;
    let mut out = Output::create(args, None)?;
    let mut image = GrayImage::new(0, 0);
    let sem = SemMetadata::default();
    while let Some(header) = frames.next_into(&mut image)? {
        let utc = match header.capture_ns {
            0 => String::new(),
            ns => info.anchor.utc(info.anchor.seconds_at(ns)),
        };
        let name = header.sequence.to_string();
        let label = FrameLabel {
            name: &name,
            seq: header.sequence,
            utc: &utc,
        };
        let overlay_name = format!("frame_{:08}.png", header.sequence);
        out.track(tracker, &image, &label, &sem, &overlay_name)?;
    }
    if frames.skipped_bytes > 0 {
        tracing::warn!(
            "{}: skipped {} bytes that were not a frame",
            frames_path.display(),
            frames.skipped_bytes
        );
    }
    out.finish()
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

/// Refuses outputs that would overwrite an input (`frames`: the frame files, or a
/// session's frames file and description); returns each frame's overlay name.
fn check_outputs(
    args: &ReplayArgs,
    frames: &[PathBuf],
    files: &Inputs,
) -> anyhow::Result<Vec<String>> {
    let mut inputs: HashMap<PathBuf, String> = HashMap::new();
    for frame in frames {
        inputs.insert(resolved(frame), format!("the frame {}", frame.display()));
    }
    let config = format!("the configuration {}", files.config.display());
    inputs.insert(resolved(files.config), config);
    if let Some(reference) = files.reference {
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

/// A progress bar on a terminal; `len`: the number of frames, when known.
fn progress_bar(len: Option<usize>) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let (bar, template) = match len {
        Some(n) => (
            ProgressBar::new(n as u64),
            "{bar:40} {pos}/{len} frames  {elapsed} (eta {eta})",
        ),
        None => (ProgressBar::no_length(), "{pos} frames  {elapsed}"),
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}
