//! `nanoforce score`: a results CSV against a session's `truth.csv`, the accuracy
//! numbers the tests and docs quote ([`crate::session::score`] computes them).
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use serde::Serialize;

use crate::session::results::read_results;
use crate::session::score::{read_truth, scorecard, Scorecard, Spread};

/// Score a results CSV against a session's truth.csv: detection, angle, apex, force.
#[derive(Debug, Args)]
#[command(long_about = LONG_ABOUT, after_long_help = AFTER_LONG_HELP)]
pub struct ScoreArgs {
    /// The session's truth.csv.
    #[arg(value_name = "TRUTH.csv")]
    pub truth: PathBuf,
    /// The results: the CSV of `nanoforce replay` (or any CSV with its first columns).
    #[arg(value_name = "RESULT.csv")]
    pub result: PathBuf,
    /// Print the numbers as one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

const LONG_ABOUT: &str = "\
Scores a results CSV against the truth.csv of a synthetic session: how many frames with \
the probe were detected, how many frames without it were reported detected anyway, and \
how far off the angle, the apex and the force are. These are the numbers the tests and \
docs/tracker.md quote.

MATCHING
Rows are matched by the file name in the `frame` column (folders are ignored). A truth \
frame with detected = 1 is a probe frame; it counts as detected when the result has \
detected = 1 (or true) and an angle. A probe frame missing from the results is a miss. \
A frame with detected = 0 in the truth that the result reports detected (with an angle) \
is a false detection.

NUMBERS
  frames                 truth rows
  detect_rate            detected probe frames / probe frames
  false_detections       frames without the probe reported detected
  angle_err_*_deg        |angle_deg - true angle_deg| over the detected probe frames:
                         median, 95th percentile, maximum
  tip_err_*_px           distance from (tip_x, tip_y) to the true apex, pixels; a
                         detected frame without an apex counts as infinite
  force_err_*_nN         |force_nN - true force_nN|, nanonewtons; a detected frame
                         without a force counts as infinite
  true_force_peak_nN     the largest |true force| over the probe frames
Percentiles interpolate linearly between the closest ranks. Without any detected probe \
frame the errors are infinite: \"-\" in the text, null in the JSON. Both files follow \
docs/conventions.md (pixels, angles, signs, units, the apex convention).";

const AFTER_LONG_HELP: &str = "\
EXAMPLES
  $ nanoforce replay replay/demo/frames --config replay/demo/probe.toml --csv /tmp/demo.csv
  $ nanoforce score replay/demo/truth.csv /tmp/demo.csv
  $ nanoforce score replay/demo/truth.csv /tmp/demo.csv --json

EXIT STATUS
  0 when both files were read and scored; 1 when a file cannot be read or lacks a
  column it needs (the message names the file and what is missing).";

/// Runs `nanoforce score`.
pub fn run(args: ScoreArgs) -> anyhow::Result<ExitCode> {
    let truth = read_truth(&args.truth)?;
    let results = read_results(&args.result)?;
    let card = scorecard(&truth, &results);
    if args.json {
        let text = serde_json::to_string_pretty(&to_json(&card))?;
        println!("{text}");
    } else {
        print!("{}", to_text(&card));
    }
    Ok(ExitCode::SUCCESS)
}

/// The JSON form of a [`Scorecard`]: keys in the order of the long help, `None`
/// (null) for an error over no frames.
#[derive(Debug, Serialize)]
pub struct ScoreJson {
    frames: usize,
    probe_frames: usize,
    detected: usize,
    detect_rate: f64,
    false_detections: usize,
    angle_err_median_deg: Option<f64>,
    angle_err_p95_deg: Option<f64>,
    angle_err_max_deg: Option<f64>,
    tip_err_median_px: Option<f64>,
    tip_err_p95_px: Option<f64>,
    tip_err_max_px: Option<f64>,
    #[serde(rename = "force_err_median_nN")]
    force_err_median_nn: Option<f64>,
    #[serde(rename = "force_err_p95_nN")]
    force_err_p95_nn: Option<f64>,
    #[serde(rename = "force_err_max_nN")]
    force_err_max_nn: Option<f64>,
    #[serde(rename = "true_force_peak_nN")]
    true_force_peak_nn: f64,
}

/// The scorecard's JSON form.
pub fn to_json(card: &Scorecard) -> ScoreJson {
    let finite = |v: f64| v.is_finite().then_some(v);
    let s = &card.score;
    ScoreJson {
        frames: s.frames,
        probe_frames: s.positives,
        detected: card.detected,
        detect_rate: s.detect_rate,
        false_detections: s.false_detections,
        angle_err_median_deg: finite(s.angle_err_median_deg),
        angle_err_p95_deg: finite(s.angle_err_p95_deg),
        angle_err_max_deg: finite(s.angle_err_max_deg),
        tip_err_median_px: finite(card.tip_err_px.median),
        tip_err_p95_px: finite(card.tip_err_px.p95),
        tip_err_max_px: finite(card.tip_err_px.max),
        force_err_median_nn: finite(card.force_err_nn.median),
        force_err_p95_nn: finite(card.force_err_nn.p95),
        force_err_max_nn: finite(card.force_err_nn.max),
        true_force_peak_nn: card.true_force_peak_nn,
    }
}

/// The scorecard as a few aligned lines of text.
pub fn to_text(card: &Scorecard) -> String {
    let s = &card.score;
    let spread = |v: &Spread, digits: usize, unit: &str| {
        let value = |x: f64| {
            if x.is_finite() {
                format!("{x:.digits$} {unit}")
            } else {
                "-".to_string()
            }
        };
        if v.median.is_finite() {
            format!(
                "median {}, p95 {}, max {}",
                value(v.median),
                value(v.p95),
                value(v.max)
            )
        } else {
            "-".into()
        }
    };
    let mut out = String::new();
    let negatives = s.frames - s.positives;
    let mut line = |name: &str, value: String| {
        let _ = writeln!(out, "{name:<17} {value}");
    };
    line(
        "frames",
        format!(
            "{} ({} with the probe, {negatives} without)",
            s.frames, s.positives
        ),
    );
    line(
        "detected",
        format!(
            "{} of {} probe frames ({:.1} %)",
            card.detected,
            s.positives,
            100.0 * s.detect_rate
        ),
    );
    line(
        "false detections",
        format!(
            "{} of {negatives} frames without the probe",
            s.false_detections
        ),
    );
    let angle = Spread {
        median: s.angle_err_median_deg,
        p95: s.angle_err_p95_deg,
        max: s.angle_err_max_deg,
    };
    line("angle error", spread(&angle, 4, "deg"));
    line("apex error", spread(&card.tip_err_px, 3, "px"));
    let mut force = spread(&card.force_err_nn, 1, "nN");
    if card.force_err_nn.max.is_finite() && card.true_force_peak_nn > 0.0 {
        let _ = write!(
            force,
            " ({:.2} % of the true peak {:.1} nN)",
            100.0 * card.force_err_nn.max / card.true_force_peak_nn,
            card.true_force_peak_nn
        );
    }
    line("force error", force);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::score::Score;

    fn card() -> Scorecard {
        Scorecard {
            score: Score {
                frames: 24,
                positives: 20,
                detect_rate: 0.95,
                false_detections: 1,
                angle_err_median_deg: 0.0271,
                angle_err_p95_deg: 0.07,
                angle_err_max_deg: 0.082,
                tip_err_median_px: 0.1,
            },
            detected: 19,
            tip_err_px: Spread {
                median: 0.1,
                p95: 0.2,
                max: f64::INFINITY,
            },
            force_err_nn: Spread {
                median: 10.0,
                p95: 40.0,
                max: 50.0,
            },
            true_force_peak_nn: 10_000.0,
        }
    }

    #[test]
    fn text_names_every_number() {
        let text = to_text(&card());
        assert_eq!(
            text,
            "frames            24 (20 with the probe, 4 without)\n\
             detected          19 of 20 probe frames (95.0 %)\n\
             false detections  1 of 4 frames without the probe\n\
             angle error       median 0.0271 deg, p95 0.0700 deg, max 0.0820 deg\n\
             apex error        median 0.100 px, p95 0.200 px, max -\n\
             force error       median 10.0 nN, p95 40.0 nN, max 50.0 nN \
             (0.50 % of the true peak 10000.0 nN)\n"
        );
    }

    #[test]
    fn json_has_null_for_infinite_errors() {
        let v = serde_json::to_value(to_json(&card())).unwrap();
        assert_eq!(v["frames"], 24);
        assert_eq!(v["detect_rate"], 0.95);
        assert!(v["tip_err_max_px"].is_null());
        assert_eq!(v["force_err_max_nN"], 50.0);
        assert_eq!(v.as_object().map(|o| o.len()), Some(15));
        let text = serde_json::to_string(&to_json(&card())).unwrap();
        assert!(
            text.starts_with("{\"frames\":24,\"probe_frames\":20,"),
            "{text}"
        );
    }
}
