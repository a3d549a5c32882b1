//! `nanoforce report`: one self-contained HTML page about a session, for people who look at
//! pictures before numbers. It shows force and angle over time, detection and confidence
//! over time, the histogram of processing times, a strip of overlay thumbnails (Figure 8
//! style) and a summary table (frames, detected, accuracy against `truth.csv` with
//! `nanoforce score`'s definitions when there is one; loop and latency figures of a
//! recording). Every plot is also written as a PNG file beside the page.
//!
//! - [`load`]: the two session shapes (replayed, recorded) read into one table of frames;
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

use self::html::{Figure, Page};
use self::load::{FrameRow, Kind, SessionData};
use self::plot::{Panel, Series, Style, BLUE, GREEN, ORANGE, RED};
use crate::session::results::ResultsError;

/// The report could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{dir}: not a session folder: {reason}")]
    NotASession { dir: PathBuf, reason: String },
    #[error(transparent)]
    Results(#[from] ResultsError),
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
    /// The replay CSV of a replayed session; default `SESSION_DIR/replay.csv`.
    pub csv: Option<PathBuf>,
    /// Most thumbnails in the strip.
    pub thumbnails: usize,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct ReportOutput {
    pub html: PathBuf,
    pub pngs: Vec<PathBuf>,
    pub frames: usize,
    pub detected: usize,
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
    let mut figures = Vec::new();
    let mut pngs = Vec::new();
    for (file, title, caption, image) in plots(&data, &mut notes) {
        let png = encode(&image, file)?;
        let path = out_dir.join(file);
        write(&path, &png)?;
        pngs.push(path);
        figures.push(Figure {
            title: title.into(),
            png,
            caption,
        });
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
    let summary = summary::table(&data);
    let page = Page {
        title: format!("nanoforce session {}", display_name(&data.dir)),
        subtitle: subtitle(&data),
        summary: &summary,
        sections: &[],
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
        frames: data.rows.len(),
        detected: data.rows.iter().filter(|r| r.detected).count(),
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

type Plot = (&'static str, &'static str, String, RgbImage);

/// The three plots (file, title, caption, picture); a note for what cannot be drawn.
fn plots(data: &SessionData, notes: &mut Vec<String>) -> Vec<Plot> {
    let x_label = if data.timed { "time (s)" } else { "frame" };
    let series = |label: &str, colour, style, f: &dyn Fn(&FrameRow) -> Option<f64>| Series {
        label: label.into(),
        points: data
            .rows
            .iter()
            .map(|r| [r.t, f(r).unwrap_or(f64::NAN)])
            .collect(),
        colour,
        style,
    };
    let peak = data
        .rows
        .iter()
        .flat_map(|r| [r.force_nn, r.true_force_nn])
        .flatten()
        .fold(0.0f64, |m, f| m.max(f.abs()));
    let (k, unit) = force_unit(peak);
    let with_truth = |measured: Series, truth: Series| {
        let has_truth = truth.points.iter().any(|p| p[1].is_finite());
        if has_truth {
            vec![truth, measured]
        } else {
            vec![measured]
        }
    };
    let force = Panel {
        title: "Force".into(),
        y_label: unit.into(),
        series: with_truth(
            series("tracked", BLUE, Style::LineDots, &|r| {
                r.force_nn.map(|f| f * k)
            }),
            series("truth", ORANGE, Style::Line, &|r| {
                r.true_force_nn.map(|f| f * k)
            }),
        ),
        y_range: None,
    };
    let angle = Panel {
        title: "Tip angle".into(),
        y_label: "degrees, CCW on screen".into(),
        series: with_truth(
            series("tracked", BLUE, Style::LineDots, &|r| r.angle_deg),
            series("truth", ORANGE, Style::Line, &|r| r.true_angle_deg),
        ),
        y_range: None,
    };
    let detection = Panel {
        title: "Detection and confidence".into(),
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
    let mut out: Vec<Plot> = vec![
        (
            "force_angle.png",
            "Force and tip angle",
            "Tracked values of every frame; gaps are frames without a detection.".into(),
            plot::panels(&[force, angle], x_label, WIDTH, 300),
        ),
        (
            "detection.png",
            "Detection and confidence",
            "Tracker confidence per frame; dots at 1 are detections, at 0 misses.".into(),
            plot::panels(&[detection], x_label, WIDTH, 260),
        ),
    ];
    let times: Vec<f64> = data.rows.iter().filter_map(|r| r.processing_ms).collect();
    if times.is_empty() {
        notes
            .push("No processing times in this session (replay with --timing to get them).".into());
    } else {
        out.push((
            "latency.png",
            "Processing time",
            format!("Tracker processing time of {} frames.", times.len()),
            plot::histogram(&times, 40, "Processing time per frame", "ms", WIDTH, 300),
        ));
    }
    out
}

fn subtitle(data: &SessionData) -> String {
    match &data.kind {
        Kind::Replayed { csv, .. } => format!(
            "Replayed session {} (results {})",
            data.dir.display(),
            csv.display()
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
