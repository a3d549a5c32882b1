//! `nanoforce report` on a replayed synthetic session: one self-contained page (every
//! picture embedded, nothing fetched), the plots as PNG files, thumbnails drawn from the
//! frames, and a summary whose accuracy is `nanoforce score`'s against truth.csv.
use std::path::Path;
use std::process::{Command, Output};

use nanoforce::scene::{FrameFormat, Session};
use nanoforce::session::results::read_results;
use nanoforce::session::score::{read_truth, score};

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

fn nanoforce(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn replayed_session(dir: &Path, n: usize) {
    Session::sequence(77, n, 640, 480)
        .write(dir, FrameFormat::Png)
        .unwrap();
    let d = dir.to_str().unwrap();
    let out = nanoforce(&[
        "replay",
        &format!("{d}/frames"),
        "--config",
        &format!("{d}/probe.toml"),
        "--csv",
        &format!("{d}/replay.csv"),
        "--timing",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The base64 payloads of the page's `data:image/png` URIs.
fn embedded_pngs(html: &str) -> Vec<&str> {
    html.split("src=\"data:image/png;base64,")
        .skip(1)
        .map(|rest| &rest[..rest.find('"').unwrap()])
        .collect()
}

#[test]
fn replayed_session_report_is_self_contained_with_plots_and_accuracy() {
    let dir = tempfile::tempdir().unwrap();
    replayed_session(dir.path(), 24);
    let out_dir = dir.path().join("out");
    let out = nanoforce(&[
        "report",
        dir.path().to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--thumbnails",
        "4",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("report of 24 frames"), "{stderr}");
    let html = std::fs::read_to_string(out_dir.join("report.html")).unwrap();

    // Self-contained: no external references of any kind.
    for external in [
        "http:",
        "https:",
        "src=\"/",
        "src=\"file",
        "<script",
        "<link",
    ] {
        assert!(!html.contains(external), "page references {external}");
    }
    // Three plots and four thumbnails, each a PNG that decodes.
    let pngs = embedded_pngs(&html);
    assert_eq!(pngs.len(), 3 + 4, "embedded pictures");
    for b64 in &pngs {
        assert!(b64.len() > 1000 && b64.len() % 4 == 0);
    }
    for (file, width) in [
        ("force_angle.png", 1000),
        ("detection.png", 1000),
        ("latency.png", 1000),
    ] {
        let img = image::open(out_dir.join(file)).unwrap();
        assert_eq!(img.width(), width, "{file}");
    }
    assert!(image::open(out_dir.join("thumbnails.png")).is_ok());

    // The summary's accuracy is `nanoforce score`'s, computed from the files.
    let truth = read_truth(&dir.path().join("truth.csv")).unwrap();
    let results = read_results(&dir.path().join("replay.csv")).unwrap();
    let s = score(&truth, &results);
    assert!(s.detect_rate > 0.8, "{s:?}");
    let detected = results.iter().filter(|r| r.detected).count();
    assert!(html.contains("<td>Frames</td><td>24</td>"), "frames row");
    assert!(html.contains(&format!("<td>{detected} (")), "detected row");
    let angle = format!(
        "median {:.4}°, p95 {:.4}°, max {:.4}°",
        s.angle_err_median_deg, s.angle_err_p95_deg, s.angle_err_max_deg
    );
    assert!(html.contains(&angle), "angle error row {angle}");
    assert!(html.contains(&format!("median {:.2} px", s.tip_err_median_px)));
    assert!(html.contains("Processing time per frame"));
    // Thumbnails are captioned with their frame and its tracked values.
    assert!(html.contains("frame_00000.png"));
    assert!(html.contains("frame_00023.png"));
}

#[test]
fn thumbnails_show_the_edges_in_figure_8_colours() {
    let dir = tempfile::tempdir().unwrap();
    replayed_session(dir.path(), 3);
    let out = nanoforce(&["report", dir.path().to_str().unwrap(), "--thumbnails", "3"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let strip = image::open(dir.path().join("report/thumbnails.png"))
        .unwrap()
        .into_rgb8();
    // Saturated red, blue and green pixels only come from the drawn edges (frames are grey).
    let count = |f: &dyn Fn(&image::Rgb<u8>) -> bool| strip.pixels().filter(|p| f(p)).count();
    let red = count(&|p| p[0] > 200 && p[1] < 90 && p[2] < 90);
    let blue = count(&|p| p[2] > 200 && p[0] < 110 && p[1] < 150);
    let green = count(&|p| p[1] > 180 && p[0] < 90 && p[2] < 110);
    // Each colour shows exactly when the replay CSV has that edge in some frame.
    let rows = read_results(&dir.path().join("replay.csv")).unwrap();
    for (k, (name, n)) in [("red", red), ("blue", blue), ("green", green)]
        .iter()
        .enumerate()
    {
        let found = rows.iter().any(|r| r.edges[k].is_some());
        assert_eq!(
            *n > 15,
            found,
            "{name}: {n} pixels, edge in the CSV: {found}"
        );
    }
    assert!(
        blue > 15 && green > 15,
        "the pyramid's faces are always in view"
    );
}

#[test]
fn missing_or_unknown_session_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = nanoforce(&["report", dir.path().to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("not a session folder") && err.contains("replay.csv"),
        "{err}"
    );
    std::fs::write(dir.path().join("replay.csv"), "no,header\n").unwrap();
    let err = String::from_utf8_lossy(&nanoforce(&["report", dir.path().to_str().unwrap()]).stderr)
        .to_string();
    assert!(err.contains("replay.csv: not a results CSV"), "{err}");
}
