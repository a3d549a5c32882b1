//! End-to-end tests of `nanoforce score`: the real binary on the demo session's truth and
//! two results CSVs kept in tests/data/score: `demo-replay.csv`, written by `nanoforce
//! replay` on replay/demo, and `demo-edited.csv`, its first six columns edited by hand
//! (a row dropped, a probe frame missed, a false detection, a detection without an
//! angle, an apex and a force left empty, a frame named with its folder, an angle 1 deg
//! off). The expected numbers were computed independently of nanoforce (a separate
//! script with the same definitions, run on the same files), to the last digit printed.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn score(args: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nanoforce"))
        .arg("score")
        .args(args)
        .output()
        .expect("the nanoforce binary runs")
}

fn score_json(result: &str) -> Value {
    let truth = repo("replay/demo/truth.csv");
    let result = repo(result);
    let json = PathBuf::from("--json");
    let output = score(&[&truth, &result, &json]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("JSON on standard output")
}

fn number(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is not a number in {v}"))
}

/// Checks `key` against an independently computed value (relative 1e-9).
fn close(v: &Value, key: &str, expected: f64) {
    let got = number(v, key);
    assert!(
        (got - expected).abs() <= 1e-9 * expected.abs().max(1e-9),
        "{key}: {got} != {expected}"
    );
}

#[test]
fn replay_csv_scores_as_computed_independently() {
    let v = score_json("tests/data/score/demo-replay.csv");
    assert_eq!(v["frames"], 24);
    assert_eq!(v["probe_frames"], 20);
    assert_eq!(v["detected"], 20);
    assert_eq!(v["false_detections"], 0);
    close(&v, "detect_rate", 1.0);
    close(&v, "angle_err_median_deg", 0.02869050000000062);
    close(&v, "angle_err_p95_deg", 0.051624549999999575);
    close(&v, "angle_err_max_deg", 0.05729700000000015);
    close(&v, "tip_err_median_px", 0.09279534317277449);
    close(&v, "tip_err_p95_px", 0.14693216370407566);
    close(&v, "tip_err_max_px", 0.1757270610919356);
    close(&v, "force_err_median_nN", 121.38379999999961);
    close(&v, "force_err_p95_nN", 213.90445000000003);
    close(&v, "force_err_max_nN", 237.95940000000337);
    close(&v, "true_force_peak_nN", 50805.9872);
}

#[test]
fn misses_false_detections_and_empty_cells_count_as_defined() {
    let v = score_json("tests/data/score/demo-edited.csv");
    assert_eq!(v["frames"], 24);
    assert_eq!(v["detected"], 18);
    assert_eq!(v["false_detections"], 1);
    close(&v, "detect_rate", 0.9);
    close(&v, "angle_err_median_deg", 0.02869050000000062);
    close(&v, "angle_err_p95_deg", 0.18503254999999832);
    close(&v, "angle_err_max_deg", 0.9427029999999998);
    close(&v, "tip_err_median_px", 0.0979416264240121);
    // One detected frame without an apex, one without a force: infinite, so null.
    assert!(v["tip_err_max_px"].is_null(), "{v}");
    assert!(v["force_err_max_nN"].is_null(), "{v}");
    assert!(v["force_err_median_nN"].is_number(), "{v}");
}

#[test]
fn text_output_reads_as_a_table() {
    let output = score(&[
        &repo("replay/demo/truth.csv"),
        &repo("tests/data/score/demo-edited.csv"),
    ]);
    assert!(output.status.success());
    let text = String::from_utf8(output.stdout).expect("UTF-8");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[0],
        "frames            24 (20 with the probe, 4 without)"
    );
    assert_eq!(lines[1], "detected          18 of 20 probe frames (90.0 %)");
    assert_eq!(
        lines[2],
        "false detections  1 of 4 frames without the probe"
    );
    assert_eq!(
        lines[3],
        "angle error       median 0.0287 deg, p95 0.1850 deg, max 0.9427 deg"
    );
    assert!(lines[4].starts_with("apex error        median 0.098 px"));
    assert!(lines[4].ends_with("max -"), "{}", lines[4]);
}

#[test]
fn a_missing_file_or_column_is_named() {
    let truth = repo("replay/demo/truth.csv");
    let missing = repo("tests/data/score/no-such.csv");
    let output = score(&[&truth, &missing]);
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        err.contains("no-such.csv") && err.contains("cannot read"),
        "{err}"
    );
    // A truth file without the truth columns names the file and the columns.
    let dir = tempfile::tempdir().expect("a temporary folder");
    let short = dir.path().join("short-truth.csv");
    std::fs::write(&short, "frame,detected\nframe_00000.png,1\n").expect("writable");
    let output = score(&[&short, &repo("tests/data/score/demo-replay.csv")]);
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        err.contains("short-truth.csv") && err.contains("angle_deg"),
        "{err}"
    );
}
