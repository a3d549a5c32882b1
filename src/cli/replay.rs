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

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use super::replay_pool::{replay_frames, Frames, Job};
use crate::config::Config;
use crate::daemon::lab::{live_trackers, probe_trackers};
use crate::hw::frames::recording::FrameFile;
use crate::session::frames::list_frames;
use crate::session::live::{is_live_session, SessionInfo, CONFIG_FILE, SESSION_FILE};
use crate::session::results;
use crate::vision::ProbeSet;

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
reference, CCW on screen), force_nN (signed as the angle; empty for a probe without a \
cantilever), tip_x, tip_y (the apex, pixels; x right, y down) - empty when not detected - \
then confidence, angle_sigma_deg (the angle's \
standard error from the frame's noise and the calibration's; on rendered frames the errors \
run 1.07-1.14 times it on every look), scale (frame pixels per \
reference pixel, where the frame measures it: for the AFM pyramid the beam edge's distance \
from the apex; empty where only the faces are fitted, which leave it free), force_saturated, red/blue/green_support (edge pixels), px_per_um, \
magnification, tip_x_um, tip_y_um (from the SEM metadata of TIFF frames: FEI/Thermo tag \
34682 or 34680, Zeiss tag 34118; empty without it, and unreadable metadata is a warning), \
red_x0, red_y0, red_x1, red_y1 and the same for blue and green (the found edge segments, \
pixels; a rigid probe's first three named edges), miss (why not detected), frame_seq, utc and frame_time_s (a recorded frame's \
capture time), processing_ms (with --timing), seq, published_s and true_force_nN (empty: \
only a live run's estimates.csv, which has these same columns, fills them) and felt \
(1: a force the operator may feel, detected and not clamped). Without --timing the \
CSV is identical from run to run.\n\n\
Several probes in one view (a configuration with [[probe]] entries): every probe is \
tracked in every frame, and each gets its own CSV in the format above, named after it: \
--csv out.csv writes out.<name>.csv for each probe name (processing_ms is then the frame's \
time for all of them). A frame where two probes' trackers place their tips on one body \
keeps it for the more confident, the other's row saying miss = other-probe.\n\n\
Overlays (--overlay DIR) are PNG files named after their frame: a PNG frame keeps its \
name (frame_00001.png), any other frame gets its full name plus .png (frame_00001.tif \
becomes frame_00001.tif.png), so x.png and x.tif never share an overlay. Outputs never \
overwrite inputs: an overlay folder that is the frames folder, or a CSV or overlay path \
that is a frame, the configuration or its reference image, is refused before anything \
is written.",
    after_help = "Examples:\n  nanoforce replay session/frames --config session/probe.toml --csv out.csv --overlay overlays/\n  \
nanoforce score session/truth.csv out.csv\n  \
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
    /// Where to write the results (with several probes: FILE's name with each probe's
    /// name before the extension, out.csv -> out.<name>.csv).
    #[arg(long, value_name = "FILE")]
    pub csv: PathBuf,
    /// Also write each frame with the found edges drawn (red, blue, green) and the apex.
    #[arg(long, value_name = "DIR")]
    pub overlay: Option<PathBuf>,
    /// Track every frame from scratch (no search centred on the previous estimate).
    #[arg(long)]
    pub no_coherence: bool,
    /// Fill the processing_ms column (makes the CSV differ between runs).
    #[arg(long)]
    pub timing: bool,
    /// Threads that track (default: every core this process may use). The CSV is the
    /// same for any number.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub threads: Option<u16>,
}

/// What a replay did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    pub frames: usize,
    /// Per probe: its name and the frames it was detected in.
    pub detected: Vec<(String, usize)>,
    pub unreadable: usize,
    /// Frames whose SEM metadata gave a pixel size.
    pub with_scale: usize,
    /// Frames whose SEM metadata had something wrong with it.
    pub metadata_warnings: usize,
    pub median_ms: Option<f64>,
}

pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    let session = is_live_session(&args.frames_dir)
        .then(|| SessionInfo::read(&args.frames_dir))
        .transpose()?;
    let (config, config_path) = load_config(&args, session.as_ref())?;
    // The trackers once now, so a bad calibration is reported before anything is
    // written.
    let references = config.reference_images();
    let probes = || match session {
        Some(_) => live_trackers(&config),
        None => probe_trackers(&config),
    };
    probes()?;
    let names: Vec<&str> = config.probes.iter().map(|p| p.name.as_str()).collect();
    let inputs = Inputs {
        config: &config_path,
        references: references.iter().flatten().copied().collect(),
        csvs: results::per_probe(&args.csv, &names),
    };
    let summary = match &session {
        Some(info) => replay_session(&args, info, &inputs, &probes)?,
        None => replay(&args, &inputs, &probes)?,
    };
    let detected = super::detected_line(&summary.detected);
    eprintln!(
        "replayed {} frames: {detected}, {} unreadable, {} with an SEM pixel size{}; median {} ms per frame (tracking)",
        summary.frames,
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

/// The files a replay reads besides the frames, which its outputs must spare, and the
/// CSVs it writes.
pub struct Inputs<'a> {
    pub config: &'a Path,
    /// The probes' reference images.
    pub references: Vec<&'a Path>,
    /// The results CSV of each probe, with its name (see [`results::per_probe`]).
    pub csvs: Vec<(String, PathBuf)>,
}

/// Writes each probe's results CSV of `frames` (overlays named `overlay_names`),
/// tracking on `args.threads` threads with trackers from `probes`.
fn write_results(
    args: &ReplayArgs,
    inputs: &Inputs,
    frames: &Frames,
    overlay_names: &[String],
    probes: &(dyn Fn() -> anyhow::Result<ProbeSet> + Sync),
) -> anyhow::Result<ReplaySummary> {
    if let Some(dir) = &args.overlay {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut csvs = Vec::with_capacity(inputs.csvs.len());
    for (_, path) in &inputs.csvs {
        let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut csv = BufWriter::new(file);
        writeln!(csv, "{}", results::header())?;
        csvs.push(csv);
    }
    let progress = progress_bar(frames.count());
    let job = Job {
        frames,
        overlay_names,
        overlay: args.overlay.as_deref(),
        timing: args.timing,
        coherence: !args.no_coherence,
    };
    let threads = args.threads.map_or_else(default_threads, usize::from);
    let done = |n: usize| progress.inc(n as u64);
    let mut counts = replay_frames(&job, threads, probes, &mut csvs, &done)?;
    progress.finish_and_clear();
    for (csv, (_, path)) in csvs.iter_mut().zip(&inputs.csvs) {
        csv.flush()
            .with_context(|| format!("writing {}", path.display()))?;
    }
    counts.times_ms.sort_by(f64::total_cmp);
    Ok(ReplaySummary {
        frames: counts.frames,
        detected: inputs
            .csvs
            .iter()
            .map(|(name, _)| name.clone())
            .zip(counts.detected.iter().copied().chain(std::iter::repeat(0)))
            .collect(),
        unreadable: counts.unreadable,
        with_scale: counts.with_scale,
        metadata_warnings: counts.metadata_warnings,
        median_ms: counts.times_ms.get(counts.times_ms.len() / 2).copied(),
    })
}

/// The cores this process may use.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Replays the frames of `args.frames_dir` into `args.csv`.
pub fn replay(
    args: &ReplayArgs,
    inputs: &Inputs,
    probes: &(dyn Fn() -> anyhow::Result<ProbeSet> + Sync),
) -> anyhow::Result<ReplaySummary> {
    let frames = list_frames(&args.frames_dir)?;
    let overlay_names = check_outputs(args, &frames, inputs)?;
    write_results(args, inputs, &Frames::Files(frames), &overlay_names, probes)
}

/// Replays a session recorded by `nanoforce run` (its `frames.nfrm`, in recorded order)
/// into `args.csv`. Frames the recording dropped leave a gap in `frame_seq`; the tracker
/// goes on across it, as the live tracker did across the frames it never saw.
pub fn replay_session(
    args: &ReplayArgs,
    info: &SessionInfo,
    inputs: &Inputs,
    probes: &(dyn Fn() -> anyhow::Result<ProbeSet> + Sync),
) -> anyhow::Result<ReplaySummary> {
    let session_json = args.frames_dir.join(SESSION_FILE);
    let Some(path) = info.frames_path(&args.frames_dir) else {
        anyhow::bail!(
            "{}: this session recorded no frames (no frames_file)",
            session_json.display()
        );
    };
    check_outputs(args, &[path.clone(), session_json], inputs)?;
    let index = FrameFile::open(&path)?.index()?;
    if index.skipped_bytes > 0 {
        tracing::warn!(
            "{}: skipped {} bytes that were not a frame",
            path.display(),
            index.skipped_bytes
        );
    }
    let overlay_names: Vec<String> = index
        .frames
        .iter()
        .map(|(h, _)| format!("frame_{:08}.png", h.sequence))
        .collect();
    let frames = Frames::Recorded {
        path,
        frames: index.frames,
        anchor: info.anchor,
    };
    write_results(args, inputs, &frames, &overlay_names, probes)
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
    for reference in &files.references {
        let what = format!("the reference image {}", reference.display());
        inputs.insert(resolved(reference), what);
    }
    let mut csvs: HashMap<PathBuf, &Path> = HashMap::new();
    for (_, path) in &files.csvs {
        let csv = resolved(path);
        if let Some(input) = inputs.get(&csv) {
            anyhow::bail!(
                "--csv {} is {input}: refusing to overwrite an input",
                path.display()
            );
        }
        csvs.insert(csv, path);
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
        if let Some(csv) = csvs.get(&out) {
            anyhow::bail!(
                "the overlay of {} would overwrite the --csv file {}",
                frame.display(),
                csv.display()
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

/// A progress bar on a terminal.
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
