//! Every live run can be tracked again: a 6 s run of the built-in simulated lab records
//! its frames, and `nanoforce replay SESSION_DIR` reproduces the live estimates (same
//! detection, same angle to 1e-6 deg) for at least 99 % of them, matched by frame_seq;
//! so does a run of two probes, probe by probe;
//! the session's times are anchored in UTC (session.json, the `utc` columns).
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

/// A CSV as rows of named cells.
fn read_rows(path: &Path) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    lines
        .map(|l| {
            let cells = l.split(',').map(str::to_string);
            header.iter().cloned().zip(cells).collect()
        })
        .collect()
}

fn only_session(state: &Path) -> PathBuf {
    let sessions: Vec<PathBuf> = std::fs::read_dir(state.join("sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sessions.len(), 1, "{sessions:?}");
    sessions[0].clone()
}

fn record_run(state: &Path, seconds: &str) -> PathBuf {
    record_run_with(state, seconds, &[])
}

/// A run of `seconds` with `extra` arguments (a `--config`), recorded under `state`.
fn record_run_with(state: &Path, seconds: &str, extra: &[&str]) -> PathBuf {
    let out = Command::new(BIN)
        .args(["run", "--quiet", "--duration-s", seconds])
        .args(extra)
        .arg("--state-dir")
        .arg(state)
        .env("RUST_LOG", "warn")
        .env_remove("NOTIFY_SOCKET")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    only_session(state)
}

fn replay(session: &Path, csv: &Path, extra: &[&str]) -> String {
    let out = Command::new(BIN)
        .arg("replay")
        .arg(session)
        .arg("--csv")
        .arg(csv)
        .args(extra)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

#[test]
fn a_recorded_live_run_replays_to_the_same_estimates() {
    let state = tempfile::tempdir().unwrap();
    let session = record_run(state.path(), "6");
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(session.join("stats.json")).unwrap())
            .unwrap();
    let recording = &stats["recording"];
    let recorded = recording["frames_recorded"].as_u64().unwrap();
    assert!(recorded > 200, "{recording}");
    assert!(recording["frames_dropped"].is_u64(), "{recording}");
    assert_eq!(recording["frames_stopped"], false, "{recording}");
    let frames_bytes = std::fs::metadata(session.join("frames.nfrm"))
        .unwrap()
        .len();
    assert_eq!(frames_bytes, recorded * (32 + 640 * 480));

    let replayed_csv = state.path().join("replayed.csv");
    let err = replay(&session, &replayed_csv, &["--threads", "1"]);
    assert!(
        err.contains(&format!("replayed {recorded} frames")),
        "{err}"
    );
    // On two threads (two chunks of frames at once) the CSV is byte-identical.
    let two_threads = state.path().join("two-threads.csv");
    replay(&session, &two_threads, &["--threads", "2"]);
    assert_eq!(
        std::fs::read(&replayed_csv).unwrap(),
        std::fs::read(&two_threads).unwrap()
    );

    assert_reproduced(&session.join("estimates.csv"), &replayed_csv, 120);
}

/// A live run of two probes replays to each probe's live estimates:
/// `estimates.<name>.csv` against the replay's `<csv>.<name>.csv`. Two cantilevers
/// (config/sim-two-probes.toml), and a cantilever beside a rigid needle
/// (config/sim-needle.toml: the needle's tracker calibrated as a named-edge template).
#[test]
fn a_recorded_run_of_two_probes_replays_to_each_probe_s_estimates() {
    for (file, names) in [
        ("sim-two-probes.toml", ["left", "right"]),
        ("sim-needle.toml", ["lever", "needle"]),
    ] {
        let state = tempfile::tempdir().unwrap();
        let config = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config")
            .join(file);
        let session = record_run_with(state.path(), "3", &["--config", config.to_str().unwrap()]);
        let err = replay(&session, &state.path().join("replayed.csv"), &[]);
        assert!(names.iter().all(|name| err.contains(name)), "{file}: {err}");
        for name in names {
            assert_reproduced(
                &session.join(format!("estimates.{name}.csv")),
                &state.path().join(format!("replayed.{name}.csv")),
                60,
            );
        }
    }
}

/// At least 99 % of the live estimates in `live_csv` (more than `min_rows` of them,
/// most detected) come out of the replay's `replayed_csv` alike: the same detection,
/// the same angle to 1e-6 deg, the same felt force, the same capture time.
fn assert_reproduced(live_csv: &Path, replayed_csv: &Path, min_rows: usize) {
    let live = read_rows(live_csv);
    let replayed: HashMap<String, HashMap<String, String>> = read_rows(replayed_csv)
        .into_iter()
        .map(|r| (r["frame_seq"].clone(), r))
        .collect();
    assert!(live.len() > min_rows, "{} published estimates", live.len());
    let mut same = 0;
    let mut detected = 0;
    let mut differences = Vec::new();
    for row in &live {
        let Some(again) = replayed.get(&row["frame_seq"]) else {
            differences.push(format!("frame {} not recorded", row["frame_seq"]));
            continue;
        };
        // One schema: detection and the force felt read alike.
        let again_detected = again["detected"] == "1";
        let live_detected = row["detected"] == "1";
        let angles = (
            row["angle_deg"].parse::<f64>(),
            again["angle_deg"].parse::<f64>(),
        );
        let matches = row["felt"] == again["felt"]
            && match (live_detected, again_detected, angles) {
                (true, true, (Ok(a), Ok(b))) => (a - b).abs() <= 1e-6,
                (false, false, _) => true,
                _ => false,
            };
        // The frame's capture time, anchored in UTC, is the same in both files.
        assert_eq!(row["utc"], again["utc"], "frame {}", row["frame_seq"]);
        assert_eq!(row["frame_time_s"], again["frame_time_s"]);
        detected += usize::from(live_detected);
        if matches {
            same += 1;
        } else {
            differences.push(format!("frame {}: {row:?} vs {again:?}", row["frame_seq"]));
        }
    }
    assert!(
        detected * 2 > live.len(),
        "{detected} of {} detected",
        live.len()
    );
    assert!(
        same * 100 >= live.len() * 99,
        "{same} of {} estimates reproduced; first differences: {:?}",
        live.len(),
        &differences[..differences.len().min(3)]
    );
}

#[test]
fn session_times_are_anchored_in_utc() {
    let state = tempfile::tempdir().unwrap();
    let before_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let session = record_run(state.path(), "1");
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(session.join("session.json")).unwrap())
            .unwrap();
    let t0_s = info["t0_unix_ns"].as_i64().unwrap() as f64 * 1e-9;
    assert!(
        (before_s - 1.0..before_s + 10.0).contains(&t0_s),
        "{info} vs {before_s}"
    );
    assert_eq!(
        info["utc_minus_monotonic_ns"].as_i64().unwrap(),
        info["t0_unix_ns"].as_i64().unwrap() - info["t0_monotonic_ns"].as_i64().unwrap()
    );
    assert_eq!(info["frames_file"], "frames.nfrm");
    assert!(info["config_file"].is_null(), "{info}");
    let t0_utc = info["t0_utc"].as_str().unwrap();
    let events = std::fs::read_to_string(session.join("events.log")).unwrap();
    assert!(
        events.starts_with(&format!("session start: t = 0 s is {t0_utc} UTC")),
        "{events}"
    );
    // Every row's utc is t0 + its time: checked on the seconds within the minute.
    let seconds_of = |utc: &str| -> f64 { utc[17..utc.len() - 1].parse().unwrap() };
    for (file, time) in [("ticks.csv", "t_s"), ("estimates.csv", "frame_time_s")] {
        let rows = read_rows(&session.join(file));
        assert!(rows.len() > 10, "{file}");
        for row in rows.iter().step_by(7) {
            let t_s: f64 = row[time].parse().unwrap();
            let utc = &row["utc"];
            assert!(utc.ends_with('Z') && utc.len() == 27, "{file}: {utc}");
            let expected = (seconds_of(t0_utc) + t_s).rem_euclid(60.0);
            let error = (seconds_of(utc) - expected + 30.0).rem_euclid(60.0) - 30.0;
            assert!(
                error.abs() < 2e-6,
                "{file}: {utc} for t = {t_s} s from {t0_utc}"
            );
        }
    }
}

#[test]
fn replay_of_a_folder_without_a_config_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(BIN)
        .arg("replay")
        .arg(dir.path())
        .args(["--csv", "x.csv"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("not a session recorded by `nanoforce run`") && err.contains("needs --config"),
        "{err}"
    );
}

#[test]
fn frames_stop_at_their_share_of_the_budget_and_the_telemetry_goes_on() {
    let state = tempfile::tempdir().unwrap();
    let sim =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml")).unwrap();
    let config = state.path().join("lab.toml");
    std::fs::write(
        &config,
        sim.replace("[daemon]\n", "[daemon]\nrecordings_max_mb = 5\n"),
    )
    .unwrap();
    let out = Command::new(BIN)
        .args(["run", "--quiet", "--duration-s", "2", "--config"])
        .arg(&config)
        .arg("--state-dir")
        .arg(state.path())
        .env("RUST_LOG", "warn")
        .env_remove("NOTIFY_SOCKET")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    // Not a failed recording: the exit status is 0.
    assert!(out.status.success(), "{err}");
    assert!(err.contains("frames: recording stopped after"), "{err}");
    let session = only_session(state.path());
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(session.join("stats.json")).unwrap())
            .unwrap();
    let recording = &stats["recording"];
    assert_eq!(recording["state"], "recording", "{recording}");
    assert_eq!(recording["frames_stopped"], true, "{recording}");
    let frame_bytes = 32 + 640 * 480;
    let share = (0.9 * 5.0 * 1024.0 * 1024.0) as u64;
    let recorded = recording["frames_recorded"].as_u64().unwrap();
    assert_eq!(recorded, share / frame_bytes, "{recording}");
    assert!(
        recording["frames_dropped"].as_u64().unwrap() > 0,
        "{recording}"
    );
    let size = std::fs::metadata(session.join("frames.nfrm"))
        .unwrap()
        .len();
    assert_eq!(size, recorded * frame_bytes);
    assert!(std::fs::read_to_string(session.join("events.log"))
        .unwrap()
        .contains("frames: recording stopped"));
    // The telemetry covers the whole run.
    let ticks = read_rows(&session.join("ticks.csv"));
    let last_t: f64 = ticks.last().unwrap()["t_s"].parse().unwrap();
    assert!(last_t > 1.5, "ticks end at {last_t} s");
    // What was recorded replays.
    let csv = state.path().join("again.csv");
    let err = replay(&session, &csv, &[]);
    assert!(
        err.contains(&format!("replayed {recorded} frames")),
        "{err}"
    );
}
