//! The estimate CSV: one row per frame, one schema ([`COLUMNS`]) for a replay's results
//! and a live run's `estimates.csv`, written here only. The first six columns are fixed
//! (`frame, detected, angle_deg, force_nN, tip_x, tip_y`, empty when not detected), the
//! rest describe the estimate: confidence, the angle's standard error from the frame's
//! noise and the calibration's (`angle_sigma_deg`), scale, whether the force is clamped
//! at the model's limit, the edges' support, the SEM's scale from the frame's metadata
//! (`px_per_um`, `magnification`, the apex in micrometres: empty without metadata), the
//! found edge segments (`red_x0,red_y0,red_x1,red_y1`, ... in frame pixels, for
//! pictures; a rigid probe's first three named edges in those columns), `miss`, where the frame came from (`frame_seq`: a recorded frame's
//! sequence number, a folder's frames count 1, 2, ... in file-name order; `utc` and
//! `frame_time_s`: its capture time, ISO 8601 UTC and on the recording's clock, empty
//! for a folder of frames), the tracker's time on it (`processing_ms`: every live run,
//! a replay with `--timing`), what only a live run knows (`seq` and `published_s`, its
//! publication; `true_force_nN`, the simulator's truth), and `felt`: 1 when the operator
//! may feel the force ([`Estimate::felt_force_nn`]). Without timing a replay's file is a
//! pure function of the frames and the configuration: run twice, it is byte-identical.
//! [`read_results`] reads it back (for `report`).
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use super::csv::Table;
use super::metadata::SemMetadata;
use crate::vision::{Edge, EdgeFit, Estimate, Miss};

/// How many of the first [`COLUMNS`] truth.csv shares, the same names in the same order
/// (`frame` to `tip_y`): `nanoforce score` pairs the two files by them.
pub const SHARED_WITH_TRUTH: usize = 6;

/// The columns of every estimate CSV nanoforce writes (a replay's results and a run's
/// `estimates.csv`), in order; docs/operations.md says what each holds.
pub const COLUMNS: [&str; 38] = [
    "frame",
    "detected",
    "angle_deg",
    "force_nN",
    "tip_x",
    "tip_y",
    "confidence",
    "angle_sigma_deg",
    "scale",
    "force_saturated",
    "red_support",
    "blue_support",
    "green_support",
    "px_per_um",
    "magnification",
    "tip_x_um",
    "tip_y_um",
    "red_x0",
    "red_y0",
    "red_x1",
    "red_y1",
    "blue_x0",
    "blue_y0",
    "blue_x1",
    "blue_y1",
    "green_x0",
    "green_y0",
    "green_x1",
    "green_y1",
    "miss",
    "frame_seq",
    "utc",
    "frame_time_s",
    "processing_ms",
    "seq",
    "published_s",
    "true_force_nN",
    "felt",
];

/// The header line (without its line break).
pub fn header() -> String {
    COLUMNS.join(",")
}

/// What a row holds besides the frame's estimate: the tracker's time on it (a replay
/// with `--timing`, and every live run), and what only a live run knows: its
/// publication sequence and time, and the simulator's true force.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RowExtras {
    pub processing_ms: Option<f64>,
    /// The daemon's publication: sequence number and time (daemon clock, seconds).
    pub published: Option<(u64, f64)>,
    pub true_force_nn: Option<f64>,
}

/// Why there is no estimate, as written in the `miss` column.
pub fn miss_name(miss: Option<Miss>) -> &'static str {
    miss.map_or("", Miss::name)
}

/// Which frame a row is about.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameLabel<'a> {
    /// The `frame` column: a file name, or a recorded frame's sequence number.
    pub name: &'a str,
    pub seq: u64,
    /// The capture time, ISO 8601 UTC (empty: unknown).
    pub utc: &'a str,
    /// The capture time on the recording's monotonic clock, seconds (None: unknown).
    pub time_s: Option<f64>,
}

/// One row for a tracked frame; `sem` is the frame's metadata (may be empty).
pub fn write_row(
    out: &mut impl Write,
    frame: &FrameLabel,
    e: &Estimate,
    sem: &SemMetadata,
    extras: &RowExtras,
) -> io::Result<()> {
    let fixed = |v: Option<f64>, digits: usize| cell(e.shown(v), digits);
    let support = |edge: Edge| e.edges[edge.index()].map_or(0, |f| f.support);
    write!(
        out,
        "{},{},{},{},{},{},{:.4},{},{},{},{},{},{},{},{},{},{},{}",
        csv_field(frame.name),
        u8::from(e.detected),
        fixed(e.angle_deg, 6),
        fixed(e.force_nn, 4),
        fixed(e.apex_px.map(|a| a[0]), 3),
        fixed(e.apex_px.map(|a| a[1]), 3),
        e.confidence,
        fixed(e.angle_sigma_deg, 6),
        cell(e.scale, 5),
        u8::from(e.force_saturated),
        support(Edge::Red),
        support(Edge::Blue),
        support(Edge::Green),
        scale_columns(e, sem),
        edge_columns(&e.edges),
        miss_name(e.miss),
        frame.seq,
        frame.utc,
    )?;
    write_stamps(out, frame, extras)?;
    writeln!(out, ",{}", u8::from(e.felt_force_nn().is_some()))
}

/// `frame_time_s,processing_ms,seq,published_s,true_force_nN`, each empty when unknown.
fn write_stamps(out: &mut impl Write, frame: &FrameLabel, x: &RowExtras) -> io::Result<()> {
    write!(
        out,
        ",{},{},{},{},{}",
        cell(frame.time_s, 6),
        cell(x.processing_ms, 3),
        x.published
            .map_or(String::new(), |(seq, _)| seq.to_string()),
        cell(x.published.map(|(_, t)| t), 6),
        x.true_force_nn.map_or(String::new(), |f| format!("{f}")),
    )
}

/// `px_per_um,magnification,tip_x_um,tip_y_um`.
fn scale_columns(e: &Estimate, sem: &SemMetadata) -> String {
    let px_per_um = sem.px_per_um();
    let apex_um = match (e.detected.then_some(e.apex_px).flatten(), px_per_um) {
        (Some(a), Some(k)) => [Some(a[0] / k), Some(a[1] / k)],
        _ => [None, None],
    };
    format!(
        "{},{},{},{}",
        cell(px_per_um, 5),
        cell(sem.magnification, 1),
        cell(apex_um[0], 4),
        cell(apex_um[1], 4)
    )
}

/// A number to `digits` places, or an empty cell.
fn cell(value: Option<f64>, digits: usize) -> String {
    value.map_or(String::new(), |v| format!("{v:.digits$}"))
}

/// The 12 edge columns: start and end of red, blue, green (empty when not found).
fn edge_columns(edges: &[Option<EdgeFit>]) -> String {
    let mut cells = Vec::with_capacity(12);
    for e in Edge::ALL {
        match &edges[e.index()] {
            Some(fit) => {
                let [x0, y0] = fit.start_px;
                let [x1, y1] = fit.end_px;
                cells.extend([x0, y0, x1, y1].map(|v| format!("{v:.2}")));
            }
            None => cells.extend(std::iter::repeat_n(String::new(), 4)),
        }
    }
    cells.join(",")
}

/// A row for a frame that could not be decoded: not detected, reason in `miss`.
pub fn write_unreadable(out: &mut impl Write, frame: &FrameLabel) -> io::Result<()> {
    write!(
        out,
        "{},0,,,,,0.0000,,,0,0,0,0{}unreadable,{},{}",
        csv_field(frame.name),
        // the 4 scale and 12 edge columns, empty
        ",".repeat(17),
        frame.seq,
        frame.utc
    )?;
    write_stamps(out, frame, &RowExtras::default())?;
    writeln!(out, ",0")
}

/// Quotes a field that holds a comma, quote or line break.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// One row of a results CSV as read back; columns the file lacks are empty.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ResultRow {
    pub frame: String,
    pub detected: bool,
    pub angle_deg: Option<f64>,
    pub force_nn: Option<f64>,
    pub tip_px: Option<[f64; 2]>,
    pub confidence: Option<f64>,
    pub px_per_um: Option<f64>,
    pub magnification: Option<f64>,
    /// Start and end of red, blue, green, frame pixels.
    pub edges: [Option<[[f64; 2]; 2]>; 3],
    pub miss: String,
    /// The frame's sequence number (absent in older results).
    pub frame_seq: Option<u64>,
    pub processing_ms: Option<f64>,
    /// The capture time on the recording's clock, seconds (`frame_time_s`).
    pub time_s: Option<f64>,
    /// The simulator's true force (a simulated live run's `true_force_nN`).
    pub true_force_nn: Option<f64>,
}

/// A results CSV that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a results CSV: {reason}")]
    Format { path: PathBuf, reason: String },
}

/// Reads a results CSV (replay's, or any with at least `frame` and `detected`).
pub fn read_results(path: &Path) -> Result<Vec<ResultRow>, ResultsError> {
    let text = std::fs::read_to_string(path).map_err(|source| ResultsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_results(&text).map_err(|reason| ResultsError::Format {
        path: path.to_path_buf(),
        reason,
    })
}

/// Parses results CSV text (RFC 4180, see [`super::csv`]).
pub fn parse_results(text: &str) -> Result<Vec<ResultRow>, String> {
    let table = Table::parse(text)?;
    let col = |name: &str| table.column(name);
    // A run's estimates.csv before it had a `frame` column names frames by `frame_seq`.
    let (Some(frame), Some(detected)) = (col("frame").or(col("frame_seq")), col("detected")) else {
        return Err("no `frame` (or `frame_seq`) and `detected` columns".into());
    };
    let names = [
        "angle_deg",
        "force_nN",
        "tip_x",
        "tip_y",
        "confidence",
        "px_per_um",
        "magnification",
        "processing_ms",
        "frame_time_s",
        "true_force_nN",
    ];
    let [angle, force, tx, ty, conf, ppu, mag, ms, time, truth] = names.map(col);
    let edge_cols: Vec<[Option<usize>; 4]> = Edge::ALL
        .iter()
        .map(|e| ["x0", "y0", "x1", "y1"].map(|k| col(&format!("{}_{k}", e.name()))))
        .collect();
    let miss = col("miss");
    let frame_seq = col("frame_seq");
    let mut rows = Vec::new();
    for record in &table.rows {
        let num = |i: Option<usize>| record.number(i);
        let flag = record.cell(Some(detected));
        if !matches!(flag, "0" | "1" | "true" | "false") {
            return Err(format!(
                "row {}: detected is {flag:?}, not 1/0",
                record.line
            ));
        }
        let time_cell = record.cell(time);
        if !time_cell.is_empty() && num(time).is_none() {
            return Err(format!(
                "row {}: frame_time_s is {time_cell:?}, not seconds",
                record.line
            ));
        }
        let mut edges = [None; 3];
        for (slot, c) in edges.iter_mut().zip(&edge_cols) {
            if let [Some(x0), Some(y0), Some(x1), Some(y1)] = c.map(num) {
                *slot = Some([[x0, y0], [x1, y1]]);
            }
        }
        rows.push(ResultRow {
            frame: record.cell(Some(frame)).to_string(),
            detected: matches!(flag, "1" | "true"),
            angle_deg: num(angle),
            force_nn: num(force),
            tip_px: num(tx).zip(num(ty)).map(|(x, y)| [x, y]),
            confidence: num(conf),
            px_per_um: num(ppu),
            magnification: num(mag),
            edges,
            miss: record.cell(miss).to_string(),
            frame_seq: record.cell(frame_seq).parse().ok(),
            processing_ms: num(ms),
            time_s: num(time),
            true_force_nn: num(truth),
        });
    }
    Ok(rows)
}

/// The results CSV of each probe: `csv` itself for one probe; for several, `csv` with
/// the probe's name before its extension (`out.csv` -> `out.left.csv`, `estimates.csv`
/// -> `estimates.left.csv`).
pub fn per_probe(csv: &Path, names: &[&str]) -> Vec<(String, PathBuf)> {
    if let [name] = names {
        return vec![(name.to_string(), csv.to_path_buf())];
    }
    let stem = csv
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().to_string());
    let ext = csv
        .extension()
        .map_or_else(|| "csv".to_string(), |e| e.to_string_lossy().to_string());
    names
        .iter()
        .map(|name| {
            (
                name.to_string(),
                csv.with_file_name(format!("{stem}.{name}.{ext}")),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_refusal_has_its_own_miss_name() {
        use crate::vision::Edge;
        let mut misses = vec![
            Miss::NoCandidates,
            Miss::Inconsistent,
            Miss::ApexOutside,
            Miss::RotationOutside,
            Miss::ScaleMismatch,
            Miss::LowConfidence,
        ];
        for e in Edge::ALL {
            misses.extend([Miss::EdgeMissing(e.into()), Miss::WrongAppearance(e.into())]);
        }
        let names: std::collections::BTreeSet<&str> =
            misses.iter().map(|&m| miss_name(Some(m))).collect();
        assert_eq!(names.len(), misses.len(), "{names:?}");
        assert_eq!(
            miss_name(Some(Miss::EdgeMissing(Edge::Green.into()))),
            "edge-missing-green"
        );
        assert_eq!(
            miss_name(Some(Miss::RotationOutside)),
            "rotation-outside-window"
        );
        assert_eq!(miss_name(None), "");
    }

    #[test]
    fn undetected_rows_have_empty_values() {
        let mut out = Vec::new();
        let sem = SemMetadata {
            pixel_size_um: Some(0.1),
            magnification: Some(2000.0),
            ..SemMetadata::default()
        };
        let label = |name| FrameLabel {
            name,
            seq: 3,
            utc: "",
            time_s: None,
        };
        write_row(
            &mut out,
            &label("f.png"),
            &Estimate::missed(Miss::Inconsistent, 0.2),
            &sem,
            &RowExtras::default(),
        )
        .unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            format!(
                "f.png,0,,,,,0.2000,,,0,0,0,0,10.00000,2000.0,,,{}inconsistent,3,,,,,,,0\n",
                ",".repeat(12)
            )
        );
        let mut out = Vec::new();
        write_unreadable(&mut out, &label("a,b.png")).unwrap();
        let line = String::from_utf8(out).unwrap();
        assert!(line.ends_with(",unreadable,3,,,,,,,0\n"), "{line}");
        let columns = header().split(',').count();
        assert_eq!(columns, COLUMNS.len());
        let cells = &super::super::csv::records(&line).unwrap()[0].cells;
        assert_eq!(cells.len(), columns);
        let rows = parse_results(&format!("{}\n{line}", header())).unwrap();
        assert_eq!(rows[0].frame, "a,b.png");
        assert!(!rows[0].detected && rows[0].tip_px.is_none());
        assert_eq!(rows[0].miss, "unreadable");
        assert_eq!(rows[0].frame_seq, Some(3));
    }

    #[test]
    fn detected_rows_read_back_with_apex_in_micrometres_and_edges() {
        let fit = |a: [f64; 2], b: [f64; 2]| EdgeFit {
            start_px: a,
            end_px: b,
            support: 40,
            contrast: 50.0,
        };
        let estimate = Estimate {
            detected: true,
            angle_deg: Some(-2.5),
            force_nn: Some(-700.25),
            force_saturated: false,
            apex_px: Some([320.5, 240.25]),
            angle_sigma_deg: Some(0.0125),
            edges: std::array::from_fn(|k| match k {
                0 => Some(fit([300.0, 200.0], [100.0, 150.0])),
                2 => Some(fit([320.5, 240.25], [340.0, 210.0])),
                _ => None,
            }),
            scale: Some(1.0),
            confidence: 0.9,
            miss: None,
        };
        let sem = SemMetadata {
            pixel_size_um: Some(0.05),
            magnification: Some(4000.0),
            ..SemMetadata::default()
        };
        let mut out = header().into_bytes();
        out.push(b'\n');
        let label = FrameLabel {
            name: "f.tif",
            seq: 17,
            utc: "2026-12-03T00:01:08.123456Z",
            time_s: Some(68.123456),
        };
        let extras = RowExtras {
            processing_ms: Some(3.25),
            ..RowExtras::default()
        };
        write_row(&mut out, &label, &estimate, &sem, &extras).unwrap();
        let text = String::from_utf8(out).unwrap();
        let row = text.lines().nth(1).unwrap();
        assert!(row.contains(",20.00000,4000.0,16.0250,12.0125,"), "{row}");
        assert!(row.contains(",0.9000,0.012500,1.00000,0,40,0,40,"), "{row}");
        let r = &parse_results(&text).unwrap()[0];
        assert!(r.detected);
        assert_eq!(r.angle_deg, Some(-2.5));
        assert_eq!(r.tip_px, Some([320.5, 240.25]));
        assert_eq!(r.px_per_um, Some(20.0));
        assert_eq!(r.edges[0], Some([[300.0, 200.0], [100.0, 150.0]]));
        assert_eq!(r.edges[1], None);
        assert_eq!(r.edges[2], Some([[320.5, 240.25], [340.0, 210.0]]));
        assert_eq!(r.processing_ms, Some(3.25));
        assert_eq!(r.frame_seq, Some(17));
        assert!(
            row.ends_with(",17,2026-12-03T00:01:08.123456Z,68.123456,3.250,,,,1"),
            "{row}"
        );
    }

    #[test]
    fn malformed_csv_is_an_error() {
        assert!(parse_results("").is_err());
        assert!(parse_results("a,b\n1,2\n").unwrap_err().contains("frame"));
        let err = parse_results("frame,detected\nf.png,maybe\n").unwrap_err();
        assert!(err.contains("row 2"), "{err}");
    }
}
