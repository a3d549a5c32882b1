//! `nanoforce report` on hostile or degenerate sessions: CSVs with a byte-order mark,
//! quoted names with commas and line breaks; frame names that point out of the session
//! (skipped, never followed); values that are not finite; statistics that cannot be
//! known (a true force of 0 throughout, a run shorter than a few loop periods), which
//! print as "n/a" rather than absurd numbers.
use std::path::Path;

use image::GrayImage;
use nanoforce::report::{write_report, ReportOptions};

/// The page and the notes of the report on `dir`, and how many thumbnails it shows.
fn report(dir: &Path) -> (String, Vec<String>, usize) {
    let out = write_report(&ReportOptions {
        session_dir: dir.to_path_buf(),
        out_dir: Some(dir.join("out")),
        csv: None,
        thumbnails: 8,
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let html = std::fs::read_to_string(&out.html).unwrap();
    (html, out.notes, out.thumbnails)
}

/// The value of the summary row `key`.
fn summary_value(html: &str, key: &str) -> String {
    let start = html
        .find(&format!("<tr><td>{key}</td><td>"))
        .unwrap_or_else(|| panic!("no row {key}"))
        + key.len()
        + 17;
    html[start..start + html[start..].find("</td>").unwrap()].to_string()
}

/// A plain grey frame (what is drawn does not matter here).
fn frame(path: &Path) {
    GrayImage::from_pixel(64, 48, image::Luma([90]))
        .save(path)
        .unwrap();
}

const RESULTS_HEADER: &str = "frame,detected,angle_deg,force_nN,tip_x,tip_y,confidence";

#[test]
fn csv_with_bom_quotes_and_line_breaks_reads_every_row() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    for name in ["a,b.png", "two\nlines.png", "plain.png"] {
        frame(&frames.join(name));
    }
    let csv = format!(
        "\u{feff}{RESULTS_HEADER}\r\n\"a,b.png\",1,0.5,10.0,20,30,0.9\r\n\
         \"two\nlines.png\",1,0.6,12.0,21,31,0.9\r\nplain.png,0,,,,,0.1\r\n"
    );
    std::fs::write(dir.path().join("replay.csv"), csv).unwrap();
    let (html, notes, thumbnails) = report(dir.path());
    assert_eq!(summary_value(&html, "Frames"), "3");
    assert_eq!(thumbnails, 3);
    assert_eq!(summary_value(&html, "Detected"), "2 (66.7 %)");
    assert!(
        !notes.iter().any(|n| n.contains("could not be read")),
        "every frame found by its name: {notes:?}"
    );
    assert_eq!(html.matches("<figcaption>a,b.png").count(), 1, "{html}");
    assert!(
        html.contains("two\nlines.png"),
        "the name with a line break"
    );
}

#[test]
fn csv_with_an_open_quote_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("replay.csv"),
        format!("{RESULTS_HEADER}\n\"open.png,1,0.5,10.0,20,30,0.9\n"),
    )
    .unwrap();
    let err = write_report(&ReportOptions {
        session_dir: dir.path().to_path_buf(),
        out_dir: Some(dir.path().join("out")),
        csv: None,
        thumbnails: 8,
    })
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("replay.csv") && err.contains("line 2") && err.contains("never closed"),
        "{err}"
    );
}

#[test]
fn frame_names_leaving_the_session_are_skipped_not_followed() {
    let root = tempfile::tempdir().unwrap();
    let session = root.path().join("session");
    let frames = session.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    frame(&frames.join("inside.png"));
    // Readable images outside the session, which the report must not open.
    let secret = root.path().join("secret.png");
    frame(&secret);
    frame(&session.join("beside.png"));
    let csv = format!(
        "{RESULTS_HEADER}\ninside.png,1,0.5,10,20,30,0.9\n../../secret.png,1,0.5,10,20,30,0.9\n\
         {},1,0.5,10,20,30,0.9\n../beside.png,1,0.5,10,20,30,0.9\n\
         sub/../../beside.png,1,0.5,10,20,30,0.9\n",
        secret.display()
    );
    std::fs::write(session.join("replay.csv"), csv).unwrap();
    let (html, notes, thumbnails) = report(&session);
    assert_eq!(
        summary_value(&html, "Frames"),
        "5",
        "every row still counts"
    );
    assert_eq!(thumbnails, 1, "one thumbnail: inside.png");
    assert!(html.contains("<figcaption>inside.png"));
    let note = notes.join(" ");
    assert!(
        note.contains("4 frame name(s) of the CSV point outside the frames folder")
            && note.contains("../../secret.png"),
        "{notes:?}"
    );
}

#[test]
fn non_finite_values_never_print() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    frame(&frames.join("f0.png"));
    frame(&frames.join("f1.png"));
    std::fs::write(
        dir.path().join("replay.csv"),
        format!(
            "{RESULTS_HEADER},px_per_um,magnification,processing_ms\n\
             f0.png,0,NaN,inf,,,NaN,0,NaN,inf\nf1.png,0,,-inf,,,0.1,,1e999,2.0\n"
        ),
    )
    .unwrap();
    // Two probe frames, neither detected: the error statistics are over no frames.
    std::fs::write(
        dir.path().join("truth.csv"),
        "frame,detected,angle_deg,force_nN,tip_x,tip_y,t_s\n\
         f0.png,1,1.0,100,10,10,0.0\nf1.png,1,NaN,inf,10,10,inf\n",
    )
    .unwrap();
    let (html, _, _) = report(dir.path());
    let table = &html[html.find("<table id=\"summary\">").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    for bad in ["NaN", "inf", "Inf"] {
        assert!(!table.contains(bad), "{bad} printed:\n{table}");
    }
    assert_eq!(
        summary_value(&html, "Angle error (truth.csv)"),
        "n/a (no detected probe frames)"
    );
    assert_eq!(
        summary_value(&html, "Apex error (truth.csv)"),
        "n/a (no detected probe frames)"
    );
    assert!(
        !table.contains("Scale (SEM metadata)"),
        "a scale of 0 px/um is no scale"
    );
}

/// A recording (`nanoforce run`'s shape) with `estimates` rows and `stats`.
fn recording(dir: &Path, estimates: &str, stats: &serde_json::Value) {
    std::fs::write(
        dir.join("estimates.csv"),
        format!(
            "frame_seq,frame_time_s,detected,angle_deg,force_nN,tip_x,tip_y,confidence,\
             processing_ms,true_force_nN\n{estimates}"
        ),
    )
    .unwrap();
    std::fs::write(dir.join("stats.json"), stats.to_string()).unwrap();
}

fn stats(duration_s: f64, ticks: u64, rate_hz: f64, true_peak_nn: f64) -> serde_json::Value {
    serde_json::json!({
        "duration_s": duration_s,
        "haptic_loop": {"ticks": ticks, "rate_hz": rate_hz, "period_us_p50": null,
                        "period_us_p99": null, "period_us_max": null, "overruns": 0},
        "frames": {"received": 2, "tracked": 2, "detected": 2, "dropped": 0,
                   "latency_ms_p50": 4.0, "latency_ms_p99": 5.0},
        "force": {"samples": 2, "true_peak_nN": true_peak_nn, "rms_error_nN": 12948.3,
                  "max_error_nN": 12948.3},
        "safety": {"stale_events": 0, "faults": 0},
    })
}

#[test]
fn a_true_peak_of_zero_and_a_run_shorter_than_the_loop_print_n_a() {
    let dir = tempfile::tempdir().unwrap();
    // The true force is 0 throughout; the tracked one is not.
    recording(
        dir.path(),
        "1,0.0,1,-1.5,12948.3,300,200,0.9,4.0,0\n2,0.0005,1,-1.5,12948.3,300,200,0.9,4.0,0\n",
        // One tick in 0.58 ms: ticks / duration would read 1721.6 Hz.
        &stats(0.000581, 1, 1721.6, 0.0),
    );
    let (html, _, _) = report(dir.path());
    let force = summary_value(&html, "Force error (against the true force)");
    assert_eq!(
        force,
        "rms 12948.3 nN (n/a % of the peak: the true force is 0 throughout), max 12948.3 nN, \
         2 frames"
    );
    let haptic = summary_value(&html, "Haptic loop");
    assert!(
        haptic.starts_with("n/a (a run of fewer than 10 loop periods)"),
        "{haptic}"
    );
    assert!(
        !html.contains("1721.6") && !html.contains("1294834468818"),
        "absurd numbers"
    );

    // A normal run still prints both.
    recording(
        dir.path(),
        "1,0.0,1,-1.5,105,300,200,0.9,4.0,100\n2,0.5,1,-1.5,95,300,200,0.9,4.0,100\n",
        &stats(2.0, 2000, 1000.0, 100.0),
    );
    let (html, _, _) = report(dir.path());
    assert_eq!(
        summary_value(&html, "Force error (against the true force)"),
        "rms 5.0 nN (5.00 % of the 100 nN peak), max 5.0 nN, 2 frames"
    );
    assert!(summary_value(&html, "Haptic loop").starts_with("1000.0 Hz;"));
}
