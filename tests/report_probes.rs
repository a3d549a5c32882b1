//! `nanoforce report` on sessions of several probes: a replayed synthetic session of two
//! probes and a two-probe recording of `nanoforce run` each get one section per probe
//! (its name, its plots, its summary rows: its score against its own truth, a
//! recording's force numbers of stats.json) and the shared parts once; a probe the
//! configuration names but whose results file is missing is an error naming the file.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use nanoforce::report::{write_report, ReportOptions};
use nanoforce::scene::{FrameFormat, Session};
use nanoforce::session::results::read_results;
use nanoforce::session::score::{read_truth, score};

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

fn nanoforce(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn succeeded(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    err
}

/// The page's section of `probe`.
fn section<'a>(html: &'a str, probe: &str) -> &'a str {
    let start = html
        .find(&format!("<section class=\"probe\" id=\"probe-{probe}\">"))
        .unwrap_or_else(|| panic!("no section for {probe}"));
    let end = start + html[start..].find("</section>").unwrap();
    &html[start..end]
}

/// The value of the row `key` in `html` (a table, or a part of the page holding one).
fn row_value(html: &str, key: &str) -> String {
    let open = format!("<tr><td>{key}</td><td>");
    let start = html
        .find(&open)
        .unwrap_or_else(|| panic!("no row {key} in {html}"))
        + open.len();
    html[start..start + html[start..].find("</td>").unwrap()].to_string()
}

/// The page's first table, the session's summary.
fn shared_summary(html: &str) -> &str {
    let start = html.find("<table id=\"summary\">").unwrap();
    &html[start..start + html[start..].find("</table>").unwrap()]
}

#[test]
fn replayed_session_of_two_probes_has_a_section_and_a_score_per_probe() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    Session::several(21, 2, 12, 640, 480)
        .write(d, FrameFormat::Png)
        .unwrap();
    let s = d.to_str().unwrap();
    succeeded(&nanoforce(&[
        "replay",
        &format!("{s}/frames"),
        "--config",
        &format!("{s}/probe.toml"),
        "--csv",
        &format!("{s}/replay.csv"),
        "--timing",
    ]));
    let out_dir = d.join("out");
    let err = succeeded(&nanoforce(&[
        "report",
        s,
        "--out",
        out_dir.to_str().unwrap(),
        "--thumbnails",
        "4",
    ]));
    let html = std::fs::read_to_string(out_dir.join("report.html")).unwrap();

    let mut detected = Vec::new();
    for name in ["probe1", "probe2"] {
        let part = section(&html, name);
        assert!(part.contains(&format!("<h2>{name}</h2>")), "{name} heading");
        // Its two plots, embedded and written beside the page.
        assert_eq!(part.matches("src=\"data:image/png;base64,").count(), 2);
        assert!(part.contains("<h3>Force and tip angle</h3>"));
        assert!(part.contains("<h3>Detection and confidence</h3>"));
        for plot in ["force_angle", "detection"] {
            let img = image::open(out_dir.join(format!("{plot}.{name}.png"))).unwrap();
            assert_eq!(img.width(), 1000, "{plot} of {name}");
        }
        // Its rows: detected from its own results, the score against its own truth.
        let results = read_results(&d.join(format!("replay.{name}.csv"))).unwrap();
        let truth = read_truth(&d.join(format!("truth.{name}.csv"))).unwrap();
        let sc = score(&truth, &results);
        let n = results.iter().filter(|r| r.detected).count();
        detected.push(format!("{name} {n} detected"));
        assert!(row_value(part, "Detected").starts_with(&format!("{n} (")));
        let file = format!("truth.{name}.csv");
        assert_eq!(
            row_value(part, &format!("Detection rate ({file})")),
            format!(
                "{:.1} % of {} probe frames",
                100.0 * sc.detect_rate,
                sc.positives
            )
        );
        assert_eq!(
            row_value(part, &format!("Angle error ({file})")),
            format!(
                "median {:.4}°, p95 {:.4}°, max {:.4}°",
                sc.angle_err_median_deg, sc.angle_err_p95_deg, sc.angle_err_max_deg
            )
        );
        assert_eq!(
            row_value(part, &format!("Apex error ({file})")),
            format!("median {:.2} px", sc.tip_err_median_px)
        );
    }
    assert!(
        html.find("id=\"probe-probe1\"") < html.find("id=\"probe-probe2\""),
        "in the configuration's order"
    );
    // The shared parts once: frames and processing time, the histogram, the strip.
    let shared = shared_summary(&html);
    assert_eq!(row_value(shared, "Frames"), "12");
    assert!(shared.contains("Processing time per frame"));
    assert!(!shared.contains("Detected"), "detections are per probe");
    assert_eq!(html.matches("<h2>Processing time</h2>").count(), 1);
    assert_eq!(html.matches("<h2>Frames</h2>").count(), 1);
    assert_eq!(
        html.matches("src=\"data:image/png;base64,").count(),
        2 * 2 + 1 + 4,
        "two plots per probe, the histogram, four thumbnails"
    );
    // Each thumbnail's caption has a line per probe.
    assert!(html.contains("<figcaption>frame_00000.png  0.00 s<br>probe1  "));
    assert_eq!(html.matches("<br>probe1  ").count(), 4);
    assert_eq!(html.matches("<br>probe2  ").count(), 4);
    assert!(
        err.contains(&format!(
            "report of 12 frames ({}, 4 thumbnails)",
            detected.join(", ")
        )),
        "{err}"
    );
}

/// The one session folder `nanoforce run` wrote under `state`.
fn recorded_session(state: &Path) -> PathBuf {
    let sessions: Vec<PathBuf> = std::fs::read_dir(state.join("sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sessions.len(), 1, "{sessions:?}");
    sessions[0].clone()
}

/// A 2 s run of the lab in `config/<file>`, recorded under `state`, and its report:
/// the session folder, the report's messages and its page.
fn recorded_report(state: &Path, file: &str) -> (PathBuf, String, String) {
    let config = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(file);
    let out = Command::new(BIN)
        .args(["run", "--quiet", "--duration-s", "2", "--config"])
        .arg(&config)
        .arg("--state-dir")
        .arg(state)
        .output()
        .unwrap();
    succeeded(&out);
    let session = recorded_session(state);
    let err = succeeded(&nanoforce(&["report", session.to_str().unwrap()]));
    let html = std::fs::read_to_string(session.join("report/report.html")).unwrap();
    (session, err, html)
}

#[test]
fn recorded_session_of_two_probes_shows_each_probes_force_numbers() {
    let state = tempfile::tempdir().unwrap();
    let (session, err, html) = recorded_report(state.path(), "sim-two-probes.toml");
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(session.join("stats.json")).unwrap())
            .unwrap();

    let num = |v: &serde_json::Value, digits: usize| {
        v.as_f64()
            .map_or("n/a".to_string(), |v| format!("{v:.digits$}"))
    };
    let mut detected = Vec::new();
    for (k, name) in ["left", "right"].into_iter().enumerate() {
        let entry = &stats["probes"][k];
        assert_eq!(entry["name"], name);
        let part = section(&html, name);
        assert!(part.contains(&format!("<h2>{name}</h2>")));
        assert!(part.contains("<h3>Force and tip angle</h3>"));
        assert!(session
            .join(format!("report/force_angle.{name}.png"))
            .is_file());
        // The stats' numbers of this probe, not of the other.
        let force = &entry["force"];
        assert!(force["samples"].as_u64().unwrap() > 0, "{stats}");
        assert_eq!(
            row_value(part, "Felt force error (stats.json)"),
            format!(
                "rms {} nN, max {} nN, {} samples; true peak {} nN",
                num(&force["rms_error_nN"], 1),
                num(&force["max_error_nN"], 1),
                force["samples"],
                num(&force["true_peak_nN"], 0),
            )
        );
        assert_eq!(
            row_value(part, "Detected (daemon)"),
            format!("{} frames", entry["frames"]["detected"])
        );
        // And the force error of its own estimates file against the true force.
        let rows = read_results(&session.join(format!("estimates.{name}.csv"))).unwrap();
        let n = rows.iter().filter(|r| r.detected).count();
        detected.push(format!("{name} {n} detected"));
        assert!(row_value(part, "Detected").starts_with(&format!("{n} (")));
        assert!(row_value(part, "Force error (against the true force)").starts_with("rms "));
    }
    let (left, right) = (section(&html, "left"), section(&html, "right"));
    assert_ne!(
        row_value(left, "Felt force error (stats.json)"),
        row_value(right, "Felt force error (stats.json)"),
        "each probe its own numbers"
    );
    // The loop, latency and safety figures, and the events, once.
    let shared = shared_summary(&html);
    for key in ["Frames", "Haptic loop", "Frames (daemon)", "Safety"] {
        row_value(shared, key);
    }
    assert_eq!(html.matches("<td>Haptic loop</td>").count(), 1);
    assert_eq!(html.matches("<h2>Events</h2>").count(), 1);
    assert!(err.contains(&format!("({},", detected.join(", "))), "{err}");

    // A recording without one probe's estimates: an error naming the file.
    std::fs::remove_file(session.join("estimates.right.csv")).unwrap();
    let out = nanoforce(&["report", session.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("estimates.right.csv") && err.contains("\"right\""),
        "{err}"
    );
}

/// A recording of a cantilever beside a needle (config/sim-needle.toml): the needle's
/// section plots its angle alone and says it has no true force; the cantilever's keeps
/// its force plot and numbers.
#[test]
fn recorded_needle_has_its_angle_and_no_force() {
    let state = tempfile::tempdir().unwrap();
    let (session, _, html) = recorded_report(state.path(), "sim-needle.toml");
    let (lever, needle) = (section(&html, "lever"), section(&html, "needle"));
    assert!(lever.contains("<h3>Force and tip angle</h3>"));
    assert!(row_value(lever, "Felt force error (stats.json)").starts_with("rms "));
    assert!(needle.contains("<h3>Tip angle</h3>") && !needle.contains("Force and tip angle"));
    assert_eq!(
        row_value(needle, "Felt force error (stats.json)"),
        "n/a: no true force (a real SEM, or a probe without a cantilever)"
    );
    assert!(session.join("report/force_angle.needle.png").is_file());
}

const TWO_PROBES: &str = "[[probe]]\nname = \"left\"\n[probe.cantilever]\nlength_um = 400\n\
spring_constant_n_per_m = 1\n[[probe]]\nname = \"right\"\n[probe.cantilever]\n\
length_um = 400\nspring_constant_n_per_m = 1\n";

fn report_error(dir: &Path, csv: Option<PathBuf>) -> String {
    write_report(&ReportOptions {
        session_dir: dir.to_path_buf(),
        out_dir: Some(dir.join("out")),
        csv,
        thumbnails: 4,
    })
    .unwrap_err()
    .to_string()
}

#[test]
fn a_probe_without_its_results_file_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("probe.toml"), TWO_PROBES).unwrap();
    // No results at all: not a session, and which files were looked for.
    let err = report_error(d, None);
    assert!(
        err.contains("not a session folder")
            && err.contains("replay.left.csv")
            && err.contains("replay.right.csv"),
        "{err}"
    );
    // One probe's results, not the other's.
    let header = nanoforce::session::results::header();
    std::fs::write(d.join("replay.left.csv"), format!("{header}\n")).unwrap();
    let err = report_error(d, None);
    let missing = d.join("replay.right.csv");
    assert!(
        err.starts_with(&format!("{}: no such file", missing.display()))
            && err.contains("probe \"right\"")
            && err.contains("probe.toml"),
        "{err}"
    );
    // --csv names the files the same way.
    std::fs::write(d.join("out.left.csv"), format!("{header}\n")).unwrap();
    let err = report_error(d, Some(d.join("out.csv")));
    assert!(err.contains("out.right.csv"), "{err}");

    // A recording (session.json, config.toml) with one probe's estimates only.
    let rec = d.join("recording");
    std::fs::create_dir(&rec).unwrap();
    std::fs::write(rec.join("session.json"), "{}").unwrap();
    std::fs::write(rec.join("config.toml"), TWO_PROBES).unwrap();
    std::fs::write(rec.join("estimates.left.csv"), format!("{header}\n")).unwrap();
    let err = report_error(&rec, None);
    assert!(
        err.contains("estimates.right.csv") && err.contains("config.toml"),
        "{err}"
    );
}
