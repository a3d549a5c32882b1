//! `nanoforce report`: one self-contained HTML page about a session, for people who look at
//! pictures before numbers. It shows force and angle over time, detection and confidence
//! over time, the histogram of processing times, a strip of overlay thumbnails (Figure 8
//! style) and a summary table (frames, detected, accuracy against `truth.csv` with
//! `nanoforce score`'s definitions when there is one; loop and latency figures of a
//! recording). Every plot is also written as a PNG file beside the page.
//!
//! A session of several probes gets one part of the page per probe, headed by its name:
//! its summary rows (detected, accuracy against its own truth, for a recording its force
//! numbers of `stats.json`), its force and angle plot and its detection plot (files
//! named as its results: `force_angle.<name>.png`, `detection.<name>.png`). What the
//! probes share shows once: frames, duration and processing time, the histogram, the
//! thumbnails (every probe drawn on each), the loop and latency figures and the events.
//! A lone probe's page has no such parts.
//!
//! - [`load`]: the two session shapes (replayed, recorded) read into one table of frames
//!   per probe;
//! - [`plot`]: the plots, drawn in pure Rust with an embedded font;
//! - [`thumbs`]: the thumbnail strip;
//! - [`html`]: the page (base64 `data:` URIs; no network, no scripts).
pub mod html;
pub mod load;
pub mod plot;
mod summary;
pub mod thumbs;

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{ImageFormat, RgbImage};

use self::html::{Figure, Page, Section};
use self::load::{FrameRow, Kind, ProbeData, SessionData};
use self::plot::{Panel, Series, Style, BLUE, GREEN, ORANGE, RED};
use crate::config::ConfigError;
use crate::session::results::{per_probe, ResultsError};

/// The report could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{dir}: not a session folder: {reason}")]
    NotASession { dir: PathBuf, reason: String },
    #[error(transparent)]
    Results(#[from] ResultsError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{path}: no such file: the results of probe {probe:?}, named in {config}")]
    MissingProbe {
        path: PathBuf,
        probe: String,
        config: PathBuf,
    },
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("encoding {what} as PNG: {source}")]
    Encode {
        what: String,
        source: image::ImageError,
    },
}

/// What to report on and where to put it.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    pub session_dir: PathBuf,
    /// Default: `SESSION_DIR/report/`.
    pub out_dir: Option<PathBuf>,
    /// The replay CSV of a replayed session; default `SESSION_DIR/replay.csv`. Of a
    /// session of several probes, each probe's file is named from it (`replay.<name>.csv`).
    pub csv: Option<PathBuf>,
    /// Most thumbnails in the strip.
    pub thumbnails: usize,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct ReportOutput {
    pub html: PathBuf,
    pub pngs: Vec<PathBuf>,
    /// The session's frames ([`SessionData::frames`]).
    pub frames: usize,
    /// Each probe's name and the frames it was detected in.
    pub detected: Vec<(String, usize)>,
    pub thumbnails: usize,
    pub notes: Vec<String>,
}

const WIDTH: u32 = 1000;

/// Writes `report.html` and the plots' PNG files.
pub fn write_report(options: &ReportOptions) -> Result<ReportOutput, ReportError> {
    let data = load::load(&options.session_dir, options.csv.as_deref())?;
    let out_dir = options
        .out_dir
        .clone()
        .unwrap_or_else(|| options.session_dir.join("report"));
    std::fs::create_dir_all(&out_dir).map_err(|source| ReportError::Write {
        path: out_dir.clone(),
        source,
    })?;
    let mut notes = Vec::new();
    let mut pngs = Vec::new();
    let mut figure = |(file, title, caption, image): Plot| -> Result<Figure, ReportError> {
        let png = encode(&image, &file)?;
        let path = out_dir.join(&file);
        write(&path, &png)?;
        pngs.push(path);
        Ok(Figure {
            title: title.into(),
            png,
            caption,
        })
    };
    // A lone probe's plots are the page's; several probes get a part each.
    let mut figures = Vec::new();
    let mut sections = Vec::new();
    for (k, probe) in data.probes.iter().enumerate() {
        let plots = probe_plots(&data, k);
        let plots = plots.into_iter().map(&mut figure);
        if data.several() {
            sections.push(Section {
                heading: probe.name.clone(),
                summary: summary::probe_table(&data, k),
                figures: plots.collect::<Result<_, _>>()?,
            });
        } else {
            figures = plots.collect::<Result<_, _>>()?;
        }
    }
    if let Some(latency) = latency_plot(&data, &mut notes) {
        figures.push(figure(latency)?);
    }
    let (thumbs, note) = thumbs::thumbnails(&data, options.thumbnails);
    notes.extend(note);
    let mut strip = Vec::new();
    for t in &thumbs {
        strip.push((encode(&t.image, "a thumbnail")?, t.caption.clone()));
    }
    if let Some(picture) = thumbs::strip(&thumbs, 3) {
        let path = out_dir.join("thumbnails.png");
        write(&path, &encode(&picture, "thumbnails.png")?)?;
        pngs.push(path);
    }
    let summary = if data.several() {
        summary::shared_table(&data)
    } else {
        summary::table(&data)
    };
    let page = Page {
        title: format!("nanoforce session {}", display_name(&data.dir)),
        subtitle: subtitle(&data),
        summary: &summary,
        sections: &sections,
        figures: &figures,
        thumbnails: &strip,
        notes: &notes,
        events: &data.events,
    };
    let html_path = out_dir.join("report.html");
    write(&html_path, html::render(&page).as_bytes())?;
    Ok(ReportOutput {
        html: html_path,
        pngs,
        frames: data.frames().len(),
        detected: data
            .probes
            .iter()
            .map(|p| (p.name.clone(), p.rows.iter().filter(|r| r.detected).count()))
            .collect(),
        thumbnails: thumbs.len(),
        notes,
    })
}

/// The factor from nN and the unit that keep `max_abs_nn` readable (nN, uN or mN).
pub fn force_unit(max_abs_nn: f64) -> (f64, &'static str) {
    if max_abs_nn >= 1e6 {
        (1e-6, "mN")
    } else if max_abs_nn >= 1e4 {
        (1e-3, "µN")
    } else {
        (1.0, "nN")
    }
}

/// A plot: its file, title, caption and picture.
type Plot = (String, &'static str, String, RgbImage);

/// The plots of probe `k`: force and angle, detection and confidence. Their files are
/// named as its results ([`per_probe`]); with several probes their panels name it.
fn probe_plots(data: &SessionData, k: usize) -> Vec<Plot> {
    let probe: &ProbeData = &data.probes[k];
    let names: Vec<&str> = data.probes.iter().map(|p| p.name.as_str()).collect();
    let file = |plain: &str| {
        per_probe(Path::new(plain), &names)[k]
            .1
            .display()
            .to_string()
    };
    let titled = |title: &str| {
        if data.several() {
            format!("{title} ({})", probe.name)
        } else {
            title.to_string()
        }
    };
    let x_label = if data.timed { "time (s)" } else { "frame" };
    let series = |label: &str, colour, style, f: &dyn Fn(&FrameRow) -> Option<f64>| Series {
        label: label.into(),
        points: probe
            .rows
            .iter()
            .map(|r| [r.t, f(r).unwrap_or(f64::NAN)])
            .collect(),
        colour,
        style,
    };
    let peak = probe
        .rows
        .iter()
        .flat_map(|r| [r.force_nn, r.true_force_nn])
        .flatten()
        .fold(0.0f64, |m, f| m.max(f.abs()));
    let (scale, unit) = force_unit(peak);
    let with_truth = |measured: Series, truth: Series| {
        let has_truth = truth.points.iter().any(|p| p[1].is_finite());
        if has_truth {
            vec![truth, measured]
        } else {
            vec![measured]
        }
    };
    let force = Panel {
        title: titled("Force"),
        y_label: unit.into(),
        series: with_truth(
            series("tracked", BLUE, Style::LineDots, &|r| {
                r.force_nn.map(|f| f * scale)
            }),
            series("truth", ORANGE, Style::Line, &|r| {
                r.true_force_nn.map(|f| f * scale)
            }),
        ),
        y_range: None,
    };
    let angle = Panel {
        title: titled("Tip angle"),
        y_label: "degrees, CCW on screen".into(),
        series: with_truth(
            series("tracked", BLUE, Style::LineDots, &|r| r.angle_deg),
            series("truth", ORANGE, Style::Line, &|r| r.true_angle_deg),
        ),
        y_range: None,
    };
    let detection = Panel {
        title: titled("Detection and confidence"),
        y_label: "0..1".into(),
        series: vec![
            series("confidence", BLUE, Style::Line, &|r| r.confidence),
            series("detected", GREEN, Style::Dots, &|r| {
                r.detected.then_some(1.0)
            }),
            series("missed", RED, Style::Dots, &|r| {
                (!r.detected).then_some(0.0)
            }),
        ],
        y_range: Some([-0.08, 1.08]),
    };
    let has_force = probe
        .rows
        .iter()
        .any(|r| r.force_nn.is_some() || r.true_force_nn.is_some());
    let (panels, title, caption) = match has_force {
        true => (
            vec![force, angle],
            "Force and tip angle",
            "Tracked values of every frame; gaps are frames without a detection.",
        ),
        false => (
            vec![angle],
            "Tip angle",
            "Tracked values of every frame; gaps are frames without a detection. No force: \
             the probe has no cantilever (a rigid tool).",
        ),
    };
    vec![
        (
            file("force_angle.png"),
            title,
            caption.into(),
            plot::panels(&panels, x_label, WIDTH, 300),
        ),
        (
            file("detection.png"),
            "Detection and confidence",
            "Tracker confidence per frame; dots at 1 are detections, at 0 misses.".into(),
            plot::panels(&[detection], x_label, WIDTH, 260),
        ),
    ]
}

/// The histogram of processing times, one per frame (the first probe's rows: the
/// probes of a frame share its time); a note when the session has none.
fn latency_plot(data: &SessionData, notes: &mut Vec<String>) -> Option<Plot> {
    let times: Vec<f64> = data
        .frames()
        .iter()
        .filter_map(|r| r.processing_ms)
        .collect();
    if times.is_empty() {
        notes
            .push("No processing times in this session (replay with --timing to get them).".into());
        return None;
    }
    Some((
        "latency.png".into(),
        "Processing time",
        format!("Tracker processing time of {} frames.", times.len()),
        plot::histogram(&times, 40, "Processing time per frame", "ms", WIDTH, 300),
    ))
}

fn subtitle(data: &SessionData) -> String {
    match &data.kind {
        Kind::Replayed { .. } => format!(
            "Replayed session {} (results {})",
            data.dir.display(),
            data.probes
                .iter()
                .map(|p| p.csv.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        Kind::Recorded => format!("Recorded by nanoforce run: {}", data.dir.display()),
    }
}

fn display_name(dir: &Path) -> String {
    dir.canonicalize()
        .ok()
        .as_deref()
        .unwrap_or(dir)
        .file_name()
        .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into())
}

fn encode(image: &RgbImage, what: &str) -> Result<Vec<u8>, ReportError> {
    let mut png = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut png), ImageFormat::Png)
        .map_err(|source| ReportError::Encode {
            what: what.into(),
            source,
        })?;
    Ok(png)
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    std::fs::write(path, bytes).map_err(|source| ReportError::Write {
        path: path.to_path_buf(),
        source,
    })
}
