//! Reading a session folder for the report, in either of its two shapes:
//!
//! - **replayed**: the session layout of docs/conventions.md (`probe.toml`,
//!   `reference.png`, `frames/`, maybe `truth.csv`) plus the CSV `nanoforce replay` wrote,
//!   by default `replay.csv` in the folder. Time comes from `truth.csv`'s `t_s` when there
//!   is one, else the frame index.
//! - **recorded** by `nanoforce run`: `estimates.csv` (one row per tracked frame, time
//!   `frame_time_s`), `config.toml`, `stats.json`, `events.log` and, when the run
//!   recorded them, overlay thumbnails in `thumbnails/`.
//!
//! The probes come from the session's configuration (`probe.toml` replayed, `config.toml`
//! recorded): a lone probe's results are the files above; of several probes (`[[probe]]`
//! entries), each has its own, named by [`per_probe`] (`replay.<name>.csv`,
//! `estimates.<name>.csv`, `truth.<name>.csv`), and a file the configuration implies but
//! the folder lacks is an error naming it. A session without a configuration, or whose
//! configuration does not load while its lone results file is there, is read as one
//! probe, its pixels counted from their centre.
//!
//! Every results CSV is the one estimate schema, read by [`read_results`]; an
//! `estimates.csv` from before it had a `frame` column is named by `frame_seq`.
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::ReportError;
use crate::config::{Config, PixelOrigin, SINGLE_NAME};
use crate::session::live::{is_live_session, CONFIG_FILE};
use crate::session::results::{per_probe, read_results, ResultRow};
use crate::session::score::{read_truth, score, Score, TruthRow};

/// One tracked frame, whichever shape the session has.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameRow {
    /// The frame's file name (replayed) or `frame <seq>` (recorded).
    pub name: String,
    /// Seconds, or the frame index when the session has no times.
    pub t: f64,
    pub detected: bool,
    pub angle_deg: Option<f64>,
    pub force_nn: Option<f64>,
    pub confidence: Option<f64>,
    pub processing_ms: Option<f64>,
    pub true_force_nn: Option<f64>,
    /// From truth.csv (replayed synthetic sessions).
    pub true_angle_deg: Option<f64>,
    /// The apex and the edges' ends in the conventions' pixel frame (converted from the
    /// CSV's `tracker.pixel_origin`), for drawing on the frames.
    pub tip_px: Option<[f64; 2]>,
    pub edges: [Option<[[f64; 2]; 2]>; 3],
    pub px_per_um: Option<f64>,
    pub magnification: Option<f64>,
    /// The frame's sequence number (recorded sessions).
    pub frame_seq: Option<u64>,
}

/// Which shape the session has.
#[derive(Debug, Clone, PartialEq)]
pub enum Kind {
    Replayed { frames_dir: PathBuf },
    Recorded,
}

/// One probe of the session and what the report knows of it.
#[derive(Debug, Clone)]
pub struct ProbeData {
    /// Its name in the configuration (`probe` for a lone probe given at the top level).
    pub name: String,
    /// Its results file.
    pub csv: PathBuf,
    /// One per frame of its results file.
    pub rows: Vec<FrameRow>,
    /// Its truth file (a replayed session with truth: `truth.csv`, `truth.<name>.csv`).
    pub truth: Option<PathBuf>,
    /// Its results scored against that truth.
    pub score: Option<Score>,
}

/// Everything the report shows.
#[derive(Debug, Clone)]
pub struct SessionData {
    pub dir: PathBuf,
    pub kind: Kind,
    /// Every probe, in the configuration's order; at least one.
    pub probes: Vec<ProbeData>,
    /// True when `t` is seconds (else frame indices).
    pub timed: bool,
    pub stats: Option<serde_json::Value>,
    pub events: Vec<String>,
}

impl SessionData {
    /// The session's frames: the first probe's rows (every probe has a row for every
    /// tracked frame, in the same order).
    pub fn frames(&self) -> &[FrameRow] {
        &self.probes[0].rows
    }

    /// True for a session of several probes (one part of the page each).
    pub fn several(&self) -> bool {
        self.probes.len() > 1
    }
}

/// The results file of a recorded session's lone probe; of several, each probe's
/// name goes before its extension ([`per_probe`]).
const ESTIMATES_FILE: &str = "estimates.csv";

/// Reads `dir`; `csv` overrides where a replayed session's results are (the lone
/// probe's file, or the name each probe's file is made from).
pub fn load(dir: &Path, csv: Option<&Path>) -> Result<SessionData, ReportError> {
    if !dir.is_dir() {
        return Err(ReportError::NotASession {
            dir: dir.to_path_buf(),
            reason: "no such folder".into(),
        });
    }
    let estimates = dir.join(ESTIMATES_FILE);
    if csv.is_none() && (estimates.is_file() || is_live_session(dir)) {
        let config = dir.join(CONFIG_FILE);
        let probes = probe_files(&config, &estimates)?;
        for (probe, path) in &probes {
            if !path.is_file() && probes.len() > 1 {
                return Err(missing(path, probe, &config));
            }
        }
        return load_recorded(dir, &probes);
    }
    let csv = csv.map_or_else(|| dir.join("replay.csv"), Path::to_path_buf);
    // A recorded session replayed again (`--csv`) has its configuration as config.toml.
    let config = [dir.join("probe.toml"), dir.join(CONFIG_FILE)]
        .into_iter()
        .find(|c| c.is_file())
        .unwrap_or_else(|| dir.join("probe.toml"));
    let probes = probe_files(&config, &csv)?;
    let found = probes.iter().filter(|(_, path)| path.is_file()).count();
    if found == 0 {
        let files: Vec<String> = probes
            .iter()
            .map(|(_, path)| path.display().to_string())
            .collect();
        let what = match probes.len() {
            1 => "the CSV of `nanoforce replay`".to_string(),
            _ => format!(
                "the CSVs of `nanoforce replay` for the probes of {}",
                config.display()
            ),
        };
        return Err(ReportError::NotASession {
            dir: dir.to_path_buf(),
            reason: format!(
                "neither estimates.csv (a recording of `nanoforce run`) nor {} ({what}; give \
                 another with --csv)",
                files.join(", ")
            ),
        });
    }
    if let Some((probe, path)) = probes.iter().find(|(_, path)| !path.is_file()) {
        return Err(missing(path, probe, &config));
    }
    load_replayed(dir, &probes)
}

/// A probe as the session's configuration gives it.
#[derive(Debug, Clone)]
struct Probe {
    name: String,
    /// Where the pixels of its CSV count from (`tracker.pixel_origin`).
    origin: PixelOrigin,
}

/// The session's probes, each with its results file made from `csv` by [`per_probe`]:
/// those of `config`, or one probe counting pixels from their centre (the default) when
/// there is no configuration, or it does not load while `csv` is there (the replay or
/// run that wrote the CSV would have refused such a file).
fn probe_files(config: &Path, csv: &Path) -> Result<Vec<(Probe, PathBuf)>, ReportError> {
    let lone = || {
        let probe = Probe {
            name: SINGLE_NAME.to_string(),
            origin: PixelOrigin::Centre,
        };
        Ok(vec![(probe, csv.to_path_buf())])
    };
    if !config.is_file() {
        return lone();
    }
    let config = match Config::load(config) {
        Ok(config) => config,
        Err(_) if csv.is_file() => return lone(),
        Err(e) => return Err(e.into()),
    };
    let names: Vec<&str> = config.probes.iter().map(|p| p.name.as_str()).collect();
    Ok(per_probe(csv, &names)
        .into_iter()
        .zip(&config.probes)
        .map(|((name, path), p)| {
            let probe = Probe {
                name,
                origin: p.tracker.pixel_origin,
            };
            (probe, path)
        })
        .collect())
}

fn missing(path: &Path, probe: &Probe, config: &Path) -> ReportError {
    ReportError::MissingProbe {
        path: path.to_path_buf(),
        probe: probe.name.clone(),
        config: config.to_path_buf(),
    }
}

fn load_replayed(dir: &Path, probes: &[(Probe, PathBuf)]) -> Result<SessionData, ReportError> {
    let names: Vec<&str> = probes.iter().map(|(p, _)| p.name.as_str()).collect();
    let truths = per_probe(&dir.join("truth.csv"), &names);
    let mut read = Vec::with_capacity(probes.len());
    for ((probe, csv), (_, truth_path)) in probes.iter().zip(truths) {
        let results = read_results(csv)?;
        let truth = if truth_path.is_file() {
            Some((read_truth(&truth_path)?, truth_path))
        } else {
            None
        };
        read.push((probe, csv, results, truth));
    }
    // Seconds when every frame of every probe has its truth's time.
    let timed = read.iter().all(|(_, _, results, truth)| {
        let by_name = truth_by_name(truth.as_ref().map(|(t, _)| t.as_slice()));
        !results.is_empty()
            && results.iter().all(|r| {
                by_name
                    .get(r.frame.as_str())
                    .is_some_and(|t| t.t_s.is_some())
            })
    });
    let probes = read
        .into_iter()
        .map(|(probe, csv, results, truth)| {
            let by_name = truth_by_name(truth.as_ref().map(|(t, _)| t.as_slice()));
            let rows = results
                .iter()
                .enumerate()
                .map(|(k, r)| {
                    let t = by_name.get(r.frame.as_str()).copied();
                    let mut row = frame_row(
                        r,
                        probe.origin,
                        t.and_then(|t| t.t_s).filter(|_| timed).unwrap_or(k as f64),
                    );
                    if let Some(t) = t.filter(|t| t.detected) {
                        row.true_angle_deg = Some(t.angle_deg).filter(|a| a.is_finite());
                        row.true_force_nn = Some(t.force_nn).filter(|f| f.is_finite());
                    }
                    row
                })
                .collect();
            ProbeData {
                name: probe.name.clone(),
                csv: csv.clone(),
                rows,
                score: truth.as_ref().map(|(t, _)| score(t, &results)),
                truth: truth.map(|(_, path)| path),
            }
        })
        .collect();
    Ok(SessionData {
        dir: dir.to_path_buf(),
        kind: Kind::Replayed {
            frames_dir: dir.join("frames"),
        },
        probes,
        timed,
        stats: None,
        events: Vec::new(),
    })
}

/// A truth file's rows by frame name.
fn truth_by_name(truth: Option<&[TruthRow]>) -> HashMap<&str, &TruthRow> {
    truth
        .into_iter()
        .flatten()
        .map(|t| (t.frame.as_str(), t))
        .collect()
}

/// A row of the estimate CSV as the report draws it, its pixels in the conventions' frame
/// (from the CSV's `tracker.pixel_origin`), at time `t`.
fn frame_row(r: &ResultRow, origin: PixelOrigin, t: f64) -> FrameRow {
    FrameRow {
        name: r.frame.clone(),
        t,
        detected: r.detected,
        angle_deg: r.angle_deg.filter(|_| r.detected),
        force_nn: r.force_nn.filter(|_| r.detected),
        confidence: r.confidence,
        processing_ms: r.processing_ms,
        true_force_nn: None,
        true_angle_deg: None,
        tip_px: r.tip_px.filter(|_| r.detected).map(|p| origin.input(p)),
        edges: r.edges.map(|e| e.map(|ends| ends.map(|p| origin.input(p)))),
        px_per_um: r.px_per_um,
        magnification: r.magnification,
        frame_seq: None,
    }
}

fn load_recorded(dir: &Path, probes: &[(Probe, PathBuf)]) -> Result<SessionData, ReportError> {
    let mut data = Vec::with_capacity(probes.len());
    for (probe, estimates) in probes {
        let results = read_results(estimates)?;
        let mut rows = Vec::with_capacity(results.len());
        for r in &results {
            let Some(t) = r.time_s else {
                return Err(ReportError::Format {
                    path: estimates.clone(),
                    reason: format!("frame {}: no frame_time_s", r.frame),
                });
            };
            rows.push(FrameRow {
                name: format!(
                    "frame {}",
                    r.frame_seq.map_or("?".into(), |s| s.to_string())
                ),
                true_force_nn: r.true_force_nn,
                frame_seq: r.frame_seq,
                ..frame_row(r, probe.origin, t)
            });
        }
        data.push(ProbeData {
            name: probe.name.clone(),
            csv: estimates.clone(),
            rows,
            truth: None,
            score: None,
        });
    }
    let stats = std::fs::read_to_string(dir.join("stats.json"))
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok());
    let events = std::fs::read_to_string(dir.join("events.log"))
        .map(|s| s.lines().map(str::to_string).collect())
        .unwrap_or_default();
    Ok(SessionData {
        dir: dir.to_path_buf(),
        kind: Kind::Recorded,
        probes: data,
        timed: true,
        stats,
        events,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recording_from_before_the_frame_column_still_loads() {
        // estimates.csv as runs wrote it before it shared the replay's schema.
        let dir = tempfile::tempdir().unwrap();
        let estimates = dir.path().join("estimates.csv");
        std::fs::write(
            &estimates,
            "seq,frame_seq,frame_time_s,published_s,detected,angle_deg,force_nN,tip_x,tip_y,\
             confidence,processing_ms,true_force_nN\n\
             1,3,0.050000,0.071000,1,-1.5,-420.5,300.5,200.25,0.9100,4.200,-400\n\
             2,4,0.066667,0.090000,0,,,,,0.1000,3.900,\n",
        )
        .unwrap();
        let rows = load(dir.path(), None).unwrap().probes.remove(0).rows;
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].frame_seq, rows[0].t), (Some(3), 0.05));
        assert_eq!(rows[0].name, "frame 3");
        assert_eq!(rows[0].force_nn, Some(-420.5));
        assert_eq!(rows[0].tip_px, Some([300.5, 200.25]));
        assert_eq!(rows[0].true_force_nn, Some(-400.0));
        assert!(!rows[1].detected && rows[1].force_nn.is_none());
        assert_eq!(rows[1].processing_ms, Some(3.9));
        std::fs::write(&estimates, "a,b\n").unwrap();
        assert!(load(dir.path(), None).is_err());
        std::fs::write(&estimates, "frame_seq,frame_time_s,detected\n1,soon,1\n").unwrap();
        let bad = load(dir.path(), None).unwrap_err().to_string();
        assert!(bad.contains("row 2"), "{bad}");
    }

    #[test]
    fn replayed_pixels_come_back_to_scene_frame() {
        let dir = tempfile::tempdir().unwrap();
        let header = crate::session::results::header();
        let cells = header.split(',').count();
        let mut row = vec![String::new(); cells];
        for (i, v) in ["f0.png", "1", "1.5", "300.0", "100.5", "200.75"]
            .iter()
            .enumerate()
        {
            row[i] = v.to_string();
        }
        let blue_x0 = header.split(',').position(|h| h == "blue_x0").unwrap();
        for (k, v) in ["10.5", "20.5", "30.5", "40.5"].iter().enumerate() {
            row[blue_x0 + k] = v.to_string();
        }
        std::fs::write(
            dir.path().join("replay.csv"),
            format!("{header}\n{}\n", row.join(",")),
        )
        .unwrap();
        let config = |origin: &str| {
            std::fs::write(
                dir.path().join("probe.toml"),
                format!(
                    "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n\
                     [tracker]\npixel_origin = \"{origin}\"\n"
                ),
            )
            .unwrap();
            load(dir.path(), None).unwrap().probes[0].rows[0].clone()
        };
        let centre = config("centre");
        assert_eq!(centre.tip_px, Some([100.5, 200.75]));
        let corner = config("corner");
        assert_eq!(corner.tip_px, Some([100.0, 200.25]));
        assert_eq!(corner.edges[1], Some([[10.0, 20.0], [30.0, 40.0]]));
    }
}
