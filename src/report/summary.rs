//! The report's summary table: (quantity, value) rows, in the order a reader asks:
//! how many frames, how many detected, how accurate (against `truth.csv`, with
//! `nanoforce score`'s definitions, or against a simulated run's true force), how fast, and
//! for a recording the loop and safety figures of its `stats.json`.
//!
//! A session of several probes splits the rows: [`shared_table`] holds what the probes
//! share (frames, duration, processing time, the SEM's scale, the loop, latency and
//! safety figures), [`probe_table`] each probe's own (detected, accuracy against its
//! truth file or true force, and for a recording its entry of `stats.json`'s `probes`).
//!
//! A number that cannot be known prints as "n/a", never as a non-finite value or a
//! division by (almost) zero: a force error relative to a true peak of 0, a loop rate of
//! a run too short to have one, an error statistic over no frames. A single non-finite
//! value prints as an empty cell.
use serde_json::Value;

use super::load::{FrameRow, Kind, ProbeData, SessionData};
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

/// The rows for a session of one probe.
pub fn table(data: &SessionData) -> Rows {
    let mut rows: Rows = Vec::new();
    let mut add = |k: &str, v: String| rows.push((k.to_string(), v));
    let probe = &data.probes[0];
    frame_rows(data, &mut add);
    detected_row(probe, &mut add);
    time_rows(data, &mut add);
    scale_rows(data, &mut add);
    score_rows(probe, &mut add);
    force_truth_rows(probe, &mut add);
    if let (Kind::Recorded, Some(stats)) = (&data.kind, &data.stats) {
        stats_rows(stats, &mut add);
    }
    rows
}

/// The rows the probes of a session of several share.
pub fn shared_table(data: &SessionData) -> Rows {
    let mut rows: Rows = Vec::new();
    let mut add = |k: &str, v: String| rows.push((k.to_string(), v));
    frame_rows(data, &mut add);
    time_rows(data, &mut add);
    scale_rows(data, &mut add);
    if let (Kind::Recorded, Some(stats)) = (&data.kind, &data.stats) {
        stats_rows(stats, &mut add);
    }
    rows
}

/// The rows of probe `k` of a session of several.
pub fn probe_table(data: &SessionData, k: usize) -> Rows {
    let mut rows: Rows = Vec::new();
    let mut add = |k: &str, v: String| rows.push((k.to_string(), v));
    let probe = &data.probes[k];
    detected_row(probe, &mut add);
    score_rows(probe, &mut add);
    force_truth_rows(probe, &mut add);
    if let (Kind::Recorded, Some(stats)) = (&data.kind, &data.stats) {
        probe_stats_rows(stats, &probe.name, &mut add);
    }
    rows
}

fn frame_rows(data: &SessionData, add: &mut impl FnMut(&str, String)) {
    add("Frames", data.frames().len().to_string());
}

fn detected_row(probe: &ProbeData, add: &mut impl FnMut(&str, String)) {
    let n = probe.rows.len();
    let detected = probe.rows.iter().filter(|r| r.detected).count();
    add(
        "Detected",
        format!(
            "{detected} ({:.1} %)",
            100.0 * detected as f64 / n.max(1) as f64
        ),
    );
}

/// Duration and processing time (one per frame: the first probe's rows).
fn time_rows(data: &SessionData, add: &mut impl FnMut(&str, String)) {
    let frames = data.frames();
    let n = frames.len();
    if data.timed && n > 1 {
        add(
            "Duration",
            format!("{:.2} s", frames[n - 1].t - frames[0].t),
        );
    }
    let times: Vec<f64> = frames.iter().filter_map(|r| r.processing_ms).collect();
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
}

/// Accuracy against the probe's truth file, labelled with its name.
fn score_rows(probe: &ProbeData, add: &mut impl FnMut(&str, String)) {
    let Some(s) = &probe.score else { return };
    let file = probe
        .truth
        .as_ref()
        .and_then(|t| t.file_name())
        .map_or_else(|| "truth.csv".into(), |f| f.to_string_lossy());
    add(
        &format!("Detection rate ({file})"),
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
        &format!("False detections ({file})"),
        format!(
            "{} of {} frames without the probe",
            s.false_detections,
            s.frames - s.positives
        ),
    );
    let none_detected = format!("{NOT_AVAILABLE} (no detected probe frames)");
    add(
        &format!("Angle error ({file})"),
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
        &format!("Apex error ({file})"),
        if s.tip_err_median_px.is_finite() {
            format!("median {} px", fixed(s.tip_err_median_px, 2))
        } else {
            none_detected
        },
    );
}

/// The SEM's scale over the frames (the first probe's rows: the metadata is the frame's).
fn scale_rows(data: &SessionData, add: &mut impl FnMut(&str, String)) {
    let range = |f: &dyn Fn(&FrameRow) -> Option<f64>| {
        let v: Vec<f64> = data.frames().iter().filter_map(f).collect();
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

fn force_truth_rows(probe: &ProbeData, add: &mut impl FnMut(&str, String)) {
    let errors: Vec<f64> = probe
        .rows
        .iter()
        .filter(|r| r.detected)
        .filter_map(|r| Some(r.force_nn? - r.true_force_nn?))
        .collect();
    if errors.is_empty() {
        return;
    }
    let peak = probe
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

/// The probe's entry of `stats.json`'s `probes` (by name): the frames it was detected in
/// and its felt force against the simulator's truth.
fn probe_stats_rows(stats: &Value, name: &str, add: &mut impl FnMut(&str, String)) {
    let Some(entry) = stats
        .get("probes")
        .and_then(Value::as_array)
        .and_then(|probes| probes.iter().find(|p| p.get("name") == Some(&name.into())))
    else {
        return;
    };
    let num = |path: &[&str]| {
        path.iter()
            .try_fold(entry, |v, k| v.get(k))
            .and_then(Value::as_f64)
    };
    let fmt = |v: Option<f64>, digits: usize| {
        v.filter(|v| v.is_finite())
            .map_or(NOT_AVAILABLE.into(), |v| fixed(v, digits))
    };
    add(
        "Detected (daemon)",
        format!("{} frames", fmt(num(&["frames", "detected"]), 0)),
    );
    let force = match num(&["force", "true_peak_nN"]) {
        // Frames from a real SEM carry no truth, and a rigid tool has no force.
        None => {
            format!("{NOT_AVAILABLE}: no true force (a real SEM, or a probe without a cantilever)")
        }
        peak => format!(
            "rms {} nN, max {} nN, {} samples; true peak {} nN",
            fmt(num(&["force", "rms_error_nN"]), 1),
            fmt(num(&["force", "max_error_nN"]), 1),
            fmt(num(&["force", "samples"]), 0),
            fmt(peak, 0),
        ),
    };
    add("Felt force error (stats.json)", force);
}
