//! The report's summary table: (quantity, value) rows, in the order a reader asks:
//! how many frames, how many detected, how accurate (against `truth.csv`, with
//! `nanoforce score`'s definitions, or against a simulated run's true force), how fast, and
//! for a recording the loop and safety figures of its `stats.json`.
//!
//! A number that cannot be known prints as "n/a", never as a non-finite value or a
//! division by (almost) zero: a force error relative to a true peak of 0, a loop rate of
//! a run too short to have one, an error statistic over no frames. A single non-finite
//! value prints as an empty cell.
use serde_json::Value;

use super::load::{Kind, SessionData};
use crate::session::score::percentile;

type Rows = Vec<(String, String)>;

/// What a number that cannot be known prints as.
pub const NOT_AVAILABLE: &str = "n/a";

/// Fewest loop ticks a rate is shown for: ticks / duration is off by up to one tick, so a
/// run shorter than this many loop periods has no meaningful rate.
pub const MIN_TICKS_FOR_RATE: f64 = 10.0;

/// `v` with `digits` decimals; empty when not finite.
pub fn fixed(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        String::new()
    }
}

/// The rows for `data`.
pub fn table(data: &SessionData) -> Rows {
    let mut rows: Rows = Vec::new();
    let mut add = |k: &str, v: String| rows.push((k.to_string(), v));
    let n = data.rows.len();
    let detected = data.rows.iter().filter(|r| r.detected).count();
    add("Frames", n.to_string());
    add(
        "Detected",
        format!(
            "{detected} ({:.1} %)",
            100.0 * detected as f64 / n.max(1) as f64
        ),
    );
    if data.timed && n > 1 {
        add(
            "Duration",
            format!("{:.2} s", data.rows[n - 1].t - data.rows[0].t),
        );
    }
    let times: Vec<f64> = data.rows.iter().filter_map(|r| r.processing_ms).collect();
    if !times.is_empty() {
        add(
            "Processing time per frame",
            format!(
                "median {:.2} ms, p99 {:.2} ms, max {:.2} ms",
                percentile(&times, 50.0),
                percentile(&times, 99.0),
                percentile(&times, 100.0)
            ),
        );
    }
    scale_rows(data, &mut add);
    if let Some(s) = &data.score {
        add(
            "Detection rate (truth.csv)",
            if s.positives == 0 {
                format!("{NOT_AVAILABLE} (no probe frames)")
            } else {
                format!(
                    "{} % of {} probe frames",
                    fixed(100.0 * s.detect_rate, 1),
                    s.positives
                )
            },
        );
        add(
            "False detections (truth.csv)",
            format!(
                "{} of {} frames without the probe",
                s.false_detections,
                s.frames - s.positives
            ),
        );
        let none_detected = format!("{NOT_AVAILABLE} (no detected probe frames)");
        add(
            "Angle error (truth.csv)",
            if s.angle_err_median_deg.is_finite() {
                format!(
                    "median {}°, p95 {}°, max {}°",
                    fixed(s.angle_err_median_deg, 4),
                    fixed(s.angle_err_p95_deg, 4),
                    fixed(s.angle_err_max_deg, 4)
                )
            } else {
                none_detected.clone()
            },
        );
        add(
            "Apex error (truth.csv)",
            if s.tip_err_median_px.is_finite() {
                format!("median {} px", fixed(s.tip_err_median_px, 2))
            } else {
                none_detected
            },
        );
    }
    force_truth_rows(data, &mut add);
    if let (Kind::Recorded, Some(stats)) = (&data.kind, &data.stats) {
        stats_rows(stats, &mut add);
    }
    rows
}

fn scale_rows(data: &SessionData, add: &mut impl FnMut(&str, String)) {
    let range = |f: &dyn Fn(&super::load::FrameRow) -> Option<f64>| {
        let v: Vec<f64> = data.rows.iter().filter_map(f).collect();
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (!v.is_empty()).then_some((lo, hi, v.len()))
    };
    if let Some((lo, hi, k)) = range(&|r| r.magnification) {
        add(
            "Magnification (SEM metadata)",
            format!("{lo:.0}x to {hi:.0}x ({k} frames)"),
        );
    }
    if let Some((lo, hi, _)) = range(&|r| r.px_per_um.filter(|k| *k > 0.0)) {
        add(
            "Scale (SEM metadata)",
            format!(
                "{} to {} px/um ({} to {} nm per pixel)",
                fixed(lo, 3),
                fixed(hi, 3),
                fixed(1e3 / hi, 1),
                fixed(1e3 / lo, 1)
            ),
        );
    }
}

fn force_truth_rows(data: &SessionData, add: &mut impl FnMut(&str, String)) {
    let errors: Vec<f64> = data
        .rows
        .iter()
        .filter(|r| r.detected)
        .filter_map(|r| Some(r.force_nn? - r.true_force_nn?))
        .collect();
    if errors.is_empty() {
        return;
    }
    let peak = data
        .rows
        .iter()
        .filter_map(|r| r.true_force_nn)
        .fold(0.0f64, |m, f| m.max(f.abs()));
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let max = errors.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    let relative = if peak > 0.0 {
        format!(
            "{} % of the {} nN peak",
            fixed(100.0 * rms / peak, 2),
            fixed(peak, 0)
        )
    } else {
        format!("{NOT_AVAILABLE} % of the peak: the true force is 0 throughout")
    };
    add(
        "Force error (against the true force)",
        format!(
            "rms {} nN ({relative}), max {} nN, {} frames",
            fixed(rms, 1),
            fixed(max, 1),
            errors.len()
        ),
    );
}

fn stats_rows(stats: &Value, add: &mut impl FnMut(&str, String)) {
    let num = |path: &[&str]| {
        path.iter()
            .try_fold(stats, |v, k| v.get(k))
            .and_then(Value::as_f64)
    };
    let fmt = |v: Option<f64>, digits: usize| v.map_or("-".into(), |v| fixed(v, digits));
    let ticks = num(&["haptic_loop", "ticks"]).unwrap_or(0.0);
    let rate = if ticks >= MIN_TICKS_FOR_RATE {
        format!("{} Hz", fmt(num(&["haptic_loop", "rate_hz"]), 1))
    } else {
        format!("{NOT_AVAILABLE} (a run of fewer than {MIN_TICKS_FOR_RATE} loop periods)")
    };
    add(
        "Haptic loop",
        format!(
            "{rate}; period p50 {} us, p99 {} us, max {} us; {} overruns",
            fmt(num(&["haptic_loop", "period_us_p50"]), 1),
            fmt(num(&["haptic_loop", "period_us_p99"]), 1),
            fmt(num(&["haptic_loop", "period_us_max"]), 1),
            fmt(num(&["haptic_loop", "overruns"]), 0),
        ),
    );
    add(
        "Frames (daemon)",
        format!(
            "{} received, {} tracked, {} dropped; latency p50 {} ms, p99 {} ms",
            fmt(num(&["frames", "received"]), 0),
            fmt(num(&["frames", "tracked"]), 0),
            fmt(num(&["frames", "dropped"]), 0),
            fmt(num(&["frames", "latency_ms_p50"]), 2),
            fmt(num(&["frames", "latency_ms_p99"]), 2),
        ),
    );
    add(
        "Safety",
        format!(
            "{} stale events, {} faults",
            fmt(num(&["safety", "stale_events"]), 0),
            fmt(num(&["safety", "faults"]), 0)
        ),
    );
}
