//! Accuracy of a results CSV against a session's `truth.csv`, the numbers `nanoforce
//! score` prints and the tests and docs quote: rows are matched by file name; a probe
//! frame counts as detected when the result says so and has an angle; a frame without
//! the probe that the result reports detected is a false detection. Over the detected
//! probe frames: the angle error's median, 95th percentile (linear interpolation between
//! closest ranks) and maximum, and the same for the apex and force errors; an empty set
//! gives infinity. docs/conventions.md describes both files.
use std::collections::HashMap;
use std::path::Path;

use super::csv::Table;
use super::results::{ResultRow, ResultsError, COLUMNS, SHARED_WITH_TRUTH};

/// One row of a `truth.csv` (docs/conventions.md, "A recorded session on disk").
#[derive(Debug, Clone, PartialEq)]
pub struct TruthRow {
    pub frame: String,
    /// The probe is in view.
    pub detected: bool,
    pub angle_deg: f64,
    pub force_nn: f64,
    pub tip_px: [f64; 2],
    pub magnification: f64,
    pub px_per_um: f64,
    pub t_s: Option<f64>,
}

/// Reads a `truth.csv`.
pub fn read_truth(path: &Path) -> Result<Vec<TruthRow>, ResultsError> {
    let format = |reason: String| ResultsError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let text = std::fs::read_to_string(path).map_err(|source| ResultsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let table = Table::parse(&text).map_err(format)?;
    let col = |name: &str| table.column(name);
    let names: [&str; SHARED_WITH_TRUTH] = std::array::from_fn(|i| COLUMNS[i]);
    let [Some(frame), Some(det), Some(angle), Some(force), Some(tx), Some(ty)] = names.map(col)
    else {
        return Err(format(format!("truth.csv needs the columns {names:?}")));
    };
    let (mag, ppu, t) = (col("magnification"), col("px_per_um"), col("t_s"));
    Ok(table
        .rows
        .iter()
        .map(|record| {
            let num = |i: Option<usize>| record.number(i).unwrap_or(f64::NAN);
            TruthRow {
                frame: record.cell(Some(frame)).to_string(),
                detected: record.cell(Some(det)) == "1",
                angle_deg: num(Some(angle)),
                force_nn: num(Some(force)),
                tip_px: [num(Some(tx)), num(Some(ty))],
                magnification: num(mag),
                px_per_um: num(ppu),
                t_s: record.number(t),
            }
        })
        .collect())
}

/// Detection and the angle and apex errors of a results CSV against its truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    pub frames: usize,
    /// Truth frames with the probe in view.
    pub positives: usize,
    pub detect_rate: f64,
    pub false_detections: usize,
    pub angle_err_median_deg: f64,
    pub angle_err_p95_deg: f64,
    pub angle_err_max_deg: f64,
    pub tip_err_median_px: f64,
}

/// Scores `results` against `truth`; a truth frame missing from the results is a miss.
pub fn score(truth: &[TruthRow], results: &[ResultRow]) -> Score {
    let by_name: HashMap<&str, &ResultRow> =
        results.iter().map(|r| (base_name(&r.frame), r)).collect();
    let (mut positives, mut detected, mut false_detections) = (0, 0, 0);
    let (mut angle_err, mut tip_err) = (Vec::new(), Vec::new());
    for t in truth {
        let found = by_name
            .get(base_name(&t.frame))
            .filter(|r| r.detected && r.angle_deg.is_some());
        match (t.detected, found) {
            (true, Some(r)) => {
                positives += 1;
                detected += 1;
                angle_err.push((r.angle_deg.unwrap_or(f64::NAN) - t.angle_deg).abs());
                tip_err.push(r.tip_px.map_or(f64::INFINITY, |p| {
                    (p[0] - t.tip_px[0]).hypot(p[1] - t.tip_px[1])
                }));
            }
            (true, None) => positives += 1,
            (false, found) => false_detections += usize::from(found.is_some()),
        }
    }
    Score {
        frames: truth.len(),
        positives,
        detect_rate: detected as f64 / positives.max(1) as f64,
        false_detections,
        angle_err_median_deg: percentile(&angle_err, 50.0),
        angle_err_p95_deg: percentile(&angle_err, 95.0),
        angle_err_max_deg: percentile(&angle_err, 100.0),
        tip_err_median_px: percentile(&tip_err, 50.0),
    }
}

/// Median, 95th percentile and maximum of a set of errors (infinity when empty).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

impl Spread {
    pub fn of(values: &[f64]) -> Self {
        Spread {
            median: percentile(values, 50.0),
            p95: percentile(values, 95.0),
            max: percentile(values, 100.0),
        }
    }
}

/// Everything `nanoforce score` reports: [`Score`], plus the spread of the apex and
/// force errors over the detected probe frames and the largest true force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scorecard {
    pub score: Score,
    /// Detected probe frames.
    pub detected: usize,
    /// Apex error, pixels (infinity for a detected frame without an apex).
    pub tip_err_px: Spread,
    /// |force - true force|, nanonewtons, over the detected probe frames whose truth
    /// has a force (infinity for such a frame without a force in the results).
    pub force_err_nn: Spread,
    /// The largest |true force| over the probe frames, nanonewtons (0 without any).
    pub true_force_peak_nn: f64,
}

/// Scores `results` against `truth` in full; [`Scorecard::score`] is [`score`]'s.
pub fn scorecard(truth: &[TruthRow], results: &[ResultRow]) -> Scorecard {
    let by_name: HashMap<&str, &ResultRow> =
        results.iter().map(|r| (base_name(&r.frame), r)).collect();
    let (mut detected, mut tip_err, mut force_err) = (0, Vec::new(), Vec::new());
    let mut true_force_peak_nn: f64 = 0.0;
    for t in truth.iter().filter(|t| t.detected) {
        if t.force_nn.is_finite() {
            true_force_peak_nn = true_force_peak_nn.max(t.force_nn.abs());
        }
        let Some(r) = by_name
            .get(base_name(&t.frame))
            .filter(|r| r.detected && r.angle_deg.is_some())
        else {
            continue;
        };
        detected += 1;
        tip_err.push(r.tip_px.map_or(f64::INFINITY, |p| {
            (p[0] - t.tip_px[0]).hypot(p[1] - t.tip_px[1])
        }));
        if t.force_nn.is_finite() {
            force_err.push(r.force_nn.map_or(f64::INFINITY, |f| (f - t.force_nn).abs()));
        }
    }
    Scorecard {
        score: score(truth, results),
        detected,
        tip_err_px: Spread::of(&tip_err),
        force_err_nn: Spread::of(&force_err),
        true_force_peak_nn,
    }
}

/// The file name without folders: rows are matched by base name.
fn base_name(frame: &str) -> &str {
    frame.rsplit(['/', '\\']).next().unwrap_or(frame)
}

/// The `q`-th percentile, interpolated linearly between closest ranks (numpy's
/// default); infinity for no values.
pub fn percentile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::INFINITY;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let pos = q / 100.0 * (v.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos - pos.floor());
    if i + 1 < v.len() {
        v[i] + frac * (v[i + 1] - v[i])
    } else {
        v[i]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(frame: &str, detected: bool, angle_deg: f64, tip: [f64; 2]) -> TruthRow {
        TruthRow {
            frame: frame.into(),
            detected,
            angle_deg,
            force_nn: 0.0,
            tip_px: tip,
            magnification: 2000.0,
            px_per_um: 10.0,
            t_s: None,
        }
    }

    fn result(frame: &str, angle: Option<f64>, tip: Option<[f64; 2]>) -> ResultRow {
        ResultRow {
            frame: frame.into(),
            detected: angle.is_some(),
            angle_deg: angle,
            tip_px: tip,
            ..ResultRow::default()
        }
    }

    #[test]
    fn percentiles_match_numpy() {
        // numpy.percentile([1, 2, 3, 4], [50, 95, 100]) = [2.5, 3.85, 4.0]
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(percentile(&v, 50.0), 2.5);
        assert!((percentile(&v, 95.0) - 3.85).abs() < 1e-12);
        assert_eq!(percentile(&v, 100.0), 4.0);
        assert_eq!(percentile(&[], 50.0), f64::INFINITY);
    }

    #[test]
    fn scores_by_base_name_and_counts_misses() {
        let t = [
            truth("a.png", true, 1.0, [10.0, 10.0]),
            truth("b.png", true, -2.0, [20.0, 20.0]),
            truth("c.png", true, 3.0, [30.0, 30.0]),
            truth("d.png", false, f64::NAN, [f64::NAN; 2]),
            truth("e.png", false, f64::NAN, [f64::NAN; 2]),
            truth("f.png", true, 0.5, [5.0, 5.0]),
        ];
        let r = [
            result("dir/a.png", Some(1.1), Some([13.0, 14.0])),
            result("b.png", Some(-2.3), Some([20.0, 21.0])),
            result("c.png", None, None),
            result("d.png", Some(0.2), Some([1.0, 1.0])),
            result("e.png", None, None),
            // f.png missing: a miss
        ];
        let s = score(&t, &r);
        assert_eq!((s.frames, s.positives, s.false_detections), (6, 4, 1));
        assert_eq!(s.detect_rate, 0.5);
        assert!((s.angle_err_median_deg - 0.2).abs() < 1e-12);
        assert!((s.angle_err_p95_deg - (0.1 + 0.95 * 0.2)).abs() < 1e-12);
        assert!((s.angle_err_max_deg - 0.3).abs() < 1e-12);
        assert_eq!(s.tip_err_median_px, 3.0);
        let none = score(&t, &[]);
        assert_eq!(none.detect_rate, 0.0);
        assert_eq!(none.angle_err_median_deg, f64::INFINITY);
    }

    #[test]
    fn scorecard_adds_apex_and_force_spreads() {
        let mut t = vec![
            truth("a.png", true, 1.0, [10.0, 10.0]),
            truth("b.png", true, 2.0, [20.0, 20.0]),
            truth("c.png", true, 3.0, [30.0, 30.0]),
            truth("d.png", false, f64::NAN, [f64::NAN; 2]),
        ];
        for (row, force) in t.iter_mut().zip([100.0, -400.0, 900.0, f64::NAN]) {
            row.force_nn = force;
        }
        let mut r = vec![
            result("a.png", Some(1.0), Some([13.0, 14.0])),
            result("b.png", Some(2.0), Some([20.0, 21.0])),
            result("c.png", None, None),
            result("d.png", None, None),
        ];
        r[0].force_nn = Some(110.0);
        r[1].force_nn = Some(-370.0);
        let card = scorecard(&t, &r);
        assert_eq!(card.score, score(&t, &r));
        assert_eq!(card.detected, 2);
        assert_eq!((card.tip_err_px.median, card.tip_err_px.max), (3.0, 5.0));
        assert_eq!(card.force_err_nn.median, 20.0);
        assert_eq!(card.force_err_nn.max, 30.0);
        assert!((card.force_err_nn.p95 - 29.0).abs() < 1e-12);
        assert_eq!(card.true_force_peak_nn, 900.0);
        // A detected frame without a force is an infinite force error.
        r[1].force_nn = None;
        assert_eq!(scorecard(&t, &r).force_err_nn.max, f64::INFINITY);
        let none = scorecard(&t, &[]);
        assert_eq!(
            (none.detected, none.force_err_nn.median),
            (0, f64::INFINITY)
        );
    }
}
