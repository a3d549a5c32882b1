//! The live data stream (`[stream]`, docs/stream.md) end to end: the built-in simulated
//! lab for 5 s with a receiver bound on loopback. Every published estimate is one
//! datagram with every field; each agrees with its row of the session's estimates.csv;
//! the haptic state arrives at its configured rate. Also: a non-loopback receiver is
//! refused without `allow_remote`, nobody listening is counted and not fatal, and the
//! Python reader in docs/stream.md reads the stream. The sim runs take turns (one lock).
use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use nanoforce::cli::run::SIM_CONFIG;
use nanoforce::config::{Config, PixelOrigin};
use nanoforce::control::Published;
use nanoforce::daemon::stats::RunStats;
use nanoforce::daemon::stream::{self, StreamShared};
use nanoforce::daemon::{lab, Daemon, ExitReason, RunOptions};
use nanoforce::hw::Clock;
use nanoforce::session::utc::UtcAnchor;
use nanoforce::vision::Estimate;
use serde_json::Value;

/// One simulated lab at a time.
static LAB: Mutex<()> = Mutex::new(());

const HAPTIC_HZ: f64 = 250.0;

/// The built-in lab with `[stream]` sending to `udp`.
fn sim_text(udp: &str, haptic_hz: f64) -> String {
    let text = SIM_CONFIG
        .replace("# udp = \"127.0.0.1:9870\"", &format!("udp = \"{udp}\""))
        .replace("haptic_hz = 0.0 ", &format!("haptic_hz = {haptic_hz:?} "));
    assert!(text.contains(&format!("udp = \"{udp}\"")) && text.contains("haptic_hz = "));
    text
}

/// Runs the lab for `seconds` with a session folder; returns its stats and the folder.
fn run_lab(text: &str, seconds: f64) -> (RunStats, tempfile::TempDir) {
    let config = Config::from_toml_str(text, Path::new("sim.toml")).unwrap();
    let clock = Clock::start();
    let devices = lab::open(&config, clock).unwrap();
    let session = tempfile::tempdir().unwrap();
    let options = RunOptions {
        duration: Some(Duration::from_secs_f64(seconds)),
        session_dir: Some(session.path().to_path_buf()),
        loop_options: config.daemon.loop_options.clone(),
        clock,
        pixel_origin: config.probes[0].tracker.pixel_origin,
        stream: config.stream.clone(),
        ..RunOptions::default()
    };
    let outcome = Daemon::start(config.teleop.clone(), devices, options)
        .unwrap()
        .wait()
        .unwrap();
    assert_eq!(outcome.exit, ExitReason::Duration);
    (outcome.stats, session)
}

/// Collects datagrams on `socket` until `stop`, each with its arrival time (Unix s); the
/// largest datagram's size goes into `largest`.
fn receive(
    socket: UdpSocket,
    stop: Arc<AtomicBool>,
    largest: Arc<AtomicUsize>,
) -> std::thread::JoinHandle<Vec<(f64, Value)>> {
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    std::thread::spawn(move || {
        let mut got = Vec::new();
        let mut buffer = [0u8; 65536];
        while !stop.load(Ordering::Relaxed) {
            if let Ok(n) = socket.recv(&mut buffer) {
                let value: Value = serde_json::from_slice(&buffer[..n])
                    .unwrap_or_else(|e| panic!("not JSON ({e}): {:?}", &buffer[..n]));
                got.push((unix_now(), value));
                largest.fetch_max(n, Ordering::Relaxed);
            }
        }
        got
    })
}

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// estimates.csv as rows of named cells, keyed by `seq`.
fn estimates_csv(path: &Path) -> HashMap<u64, HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|line| {
            let row: HashMap<String, String> = header
                .iter()
                .cloned()
                .zip(line.split(',').map(String::from))
                .collect();
            (row["seq"].parse().unwrap(), row)
        })
        .collect()
}

fn number(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is not a number: {v}"))
}

/// A number when `known`, else null; checked against the CSV cell (empty when unknown),
/// which prints it to `decimals` places.
fn check_against_csv(v: &Value, key: &str, cell: &str, known: bool, decimals: i32) {
    if !known {
        assert!(v[key].is_null(), "{key} must be null: {v}");
        return;
    }
    let got = number(v, key);
    let want: f64 = cell
        .parse()
        .unwrap_or_else(|_| panic!("{key}: csv {cell:?}"));
    assert!(
        (got - want).abs() <= 0.5 * 10f64.powi(-decimals) * (1.0 + 1e-9) + 1e-12 * want.abs(),
        "{key}: datagram {got}, estimates.csv {want}"
    );
}

/// `YYYY-MM-DDTHH:MM:SS.ffffffZ`, and the Unix seconds it means.
fn parse_utc(text: &str) -> f64 {
    let b = text.as_bytes();
    assert!(
        text.len() == 27 && b[4] == b'-' && b[10] == b'T' && b[19] == b'.' && b[26] == b'Z',
        "{text}"
    );
    let n = |r: std::ops::Range<usize>| -> i64 { text[r].parse().unwrap() };
    let (y, m, d) = (n(0..4), n(5..7), n(8..10));
    // days_from_civil (proleptic Gregorian).
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    (days * 86_400 + n(11..13) * 3600 + n(14..16) * 60 + n(17..19)) as f64 + n(20..26) as f64 * 1e-6
}

#[test]
fn every_estimate_and_the_haptic_state_arrive_with_every_field() {
    let _turn = LAB.lock().unwrap_or_else(|e| e.into_inner());
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = socket.local_addr().unwrap().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let largest = Arc::new(AtomicUsize::new(0));
    let receiver = receive(socket, stop.clone(), largest.clone());
    let (stats, session) = run_lab(&sim_text(&addr, HAPTIC_HZ), 5.0);
    std::thread::sleep(Duration::from_millis(300));
    stop.store(true, Ordering::Relaxed);
    let got = receiver.join().unwrap();
    let csv = estimates_csv(&session.path().join("estimates.csv"));
    let published = stats.frames.tracked;
    assert_eq!(csv.len() as u64, published, "estimates.csv holds the run");
    let streamed = stats.stream.expect("stream stats");
    eprintln!("{streamed:?}; {published} estimates published");
    assert_eq!(
        (streamed.estimates_dropped, streamed.haptic_dropped),
        (0, 0)
    );
    assert_eq!(streamed.send_errors, 0);

    let (estimates, haptic): (Vec<_>, Vec<_>) =
        got.iter().partition(|(_, v)| v["kind"] == "estimate");
    assert!(haptic.iter().all(|(_, v)| v["kind"] == "haptic"));
    let arrived = estimates.len() as f64 / published as f64;
    eprintln!(
        "{} of {published} estimates arrived ({:.1} %), {} haptic datagrams",
        estimates.len(),
        100.0 * arrived,
        haptic.len()
    );
    assert!(arrived >= 0.9, "{arrived}");
    // docs/stream.md: "at most about 400 bytes".
    let largest = largest.load(Ordering::Relaxed);
    eprintln!("largest datagram: {largest} bytes");
    assert!(largest <= 450, "{largest}");
    assert!(published > 200, "60 frames/s for 5 s: {published}");

    let mut detected = 0;
    for (received_unix_s, v) in &estimates {
        let seq = v["seq"].as_u64().unwrap_or_else(|| panic!("seq: {v}"));
        let row = &csv[&seq];
        assert_eq!(
            v["frame_seq"].as_u64().map(|s| s.to_string()),
            Some(row["frame_seq"].clone())
        );
        let is_detected = v["detected"].as_bool().unwrap_or_else(|| panic!("{v}"));
        assert_eq!(row["detected"], if is_detected { "1" } else { "0" });
        detected += usize::from(is_detected);
        // The datagram in full, the CSV to its places.
        check_against_csv(v, "t_s", &row["frame_time_s"], true, 6);
        check_against_csv(v, "force_nN", &row["force_nN"], is_detected, 4);
        check_against_csv(v, "angle_deg", &row["angle_deg"], is_detected, 6);
        check_against_csv(v, "tip_x", &row["tip_x"], is_detected, 3);
        check_against_csv(v, "tip_y", &row["tip_y"], is_detected, 3);
        check_against_csv(v, "confidence", &row["confidence"], true, 4);
        for key in ["force_saturated", "felt"] {
            let flag = v[key].as_bool().unwrap_or_else(|| panic!("{key}: {v}"));
            assert_eq!(row[key], if flag { "1" } else { "0" }, "{key}: {v}");
        }
        let confidence = number(v, "confidence");
        assert!((0.0..=1.0).contains(&confidence), "{v}");
        let sigma = &v["angle_sigma_deg"];
        assert!(
            sigma.is_null() || (is_detected && sigma.as_f64().is_some_and(|s| s >= 0.0)),
            "{v}"
        );
        // Wall-clock time: the capture's, a few ms before arrival, and in both spellings.
        let unix_s = number(v, "unix_s");
        let utc_s = parse_utc(v["utc"].as_str().unwrap_or_else(|| panic!("utc: {v}")));
        assert!((utc_s - unix_s).abs() < 2e-6, "{v}");
        let age_s = received_unix_s - unix_s;
        assert!(
            (0.0..1.0).contains(&age_s),
            "arrived {age_s} s after capture: {v}"
        );
        assert_eq!(v["probe"], 0, "the lone probe: {v}");
        assert_eq!(
            v.as_object().unwrap().len(),
            16,
            "no field more or less: {v}"
        );
    }
    assert!(detected as f64 > 0.9 * estimates.len() as f64, "{detected}");
    // One timebase: wall-clock differences are daemon-clock differences.
    let (first, last) = (&estimates[0].1, &estimates[estimates.len() - 1].1);
    let drift = (number(last, "unix_s") - number(first, "unix_s"))
        - (number(last, "t_s") - number(first, "t_s"));
    assert!(drift.abs() < 1e-5, "{drift}");

    // The haptic state: its rate, no gaps, every field.
    assert!(!haptic.is_empty());
    let t = |i: usize| number(&haptic[i].1, "t_s");
    let span_s = t(haptic.len() - 1) - t(0);
    let rate_hz = (haptic.len() - 1) as f64 / span_s;
    let over_run_hz = haptic.len() as f64 / stats.duration_s;
    // The stream follows the loop's ticks: a loop the host stalls (below its 1 kHz)
    // sends fewer, at most in the loop's proportion (a stall shorter than the stream's
    // period costs it nothing), and never catches up with a burst.
    let expected_hz = HAPTIC_HZ * (stats.haptic_loop.rate_hz / 1000.0).min(1.0);
    eprintln!(
        "haptic stream: {rate_hz:.1} Hz over its span, {over_run_hz:.1} Hz over the run, \
         {expected_hz:.1} Hz expected from the loop's {:.1} Hz",
        stats.haptic_loop.rate_hz
    );
    for hz in [rate_hz, over_run_hz] {
        assert!(hz >= 0.9 * expected_hz && hz <= 1.1 * HAPTIC_HZ, "{hz} Hz");
    }
    assert_eq!(streamed.haptic_sent, haptic.len() as u64);
    for (i, (_, v)) in haptic.iter().enumerate() {
        assert_eq!(v["seq"].as_u64(), Some(i as u64 + 1), "no gaps: {v}");
        let state = v["state"].as_str().unwrap_or_else(|| panic!("{v}"));
        assert!(
            ["waiting-for-centre", "engaged", "haptic-fault", "daq-fault"].contains(&state),
            "{v}"
        );
        for key in ["position_mm", "stylus_force_N", "stage_velocity_um_s"] {
            let axes = v[key].as_array().unwrap_or_else(|| panic!("{key}: {v}"));
            assert!(
                axes.len() == 3 && axes.iter().all(Value::is_f64),
                "{key}: {v}"
            );
        }
        // The simulated stylus stays inside a PHANToM's workspace and force range.
        assert!(v["position_mm"]
            .as_array()
            .unwrap()
            .iter()
            .all(|p| p.as_f64().unwrap().abs() < 200.0));
        assert!(v["stylus_force_N"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f.as_f64().unwrap().abs() < 10.0));
        number(v, "rendered_force_nN");
        number(v, "unix_s");
        parse_utc(v["utc"].as_str().unwrap());
        assert!(v["press_blocked"].is_boolean(), "{v}");
        assert_eq!(v["probe"], 0, "the lone probe is felt: {v}");
        assert_eq!(v.as_object().unwrap().len(), 12, "{v}");
    }
    let engaged = haptic
        .iter()
        .filter(|(_, v)| v["state"] == "engaged")
        .count();
    assert!(
        engaged > haptic.len() / 2,
        "the simulated operator engaged: {engaged}"
    );
}

#[test]
fn a_remote_receiver_needs_allow_remote() {
    let text = sim_text("192.168.1.20:9870", 0.0);
    let err = Config::from_toml_str(&text, Path::new("lab.toml")).unwrap_err();
    assert_eq!(
        err.to_string(),
        "lab.toml: stream.udp is not a loopback address: the stream is not encrypted and \
         anyone on that network may read it; set stream.allow_remote = true to send it \
         there anyway, got \"192.168.1.20:9870\""
    );
    let allowed = text.replace("allow_remote = false", "allow_remote = true");
    let config = Config::from_toml_str(&allowed, Path::new("lab.toml")).unwrap();
    assert_eq!(config.stream.udp.unwrap().to_string(), "192.168.1.20:9870");

    // The daemon refuses to start on it, before opening anything, and says why.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lab.toml");
    std::fs::write(&path, &text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_nanoforce"))
        .args([
            "run",
            "--no-record",
            "--quiet",
            "--duration-s",
            "1",
            "--config",
        ])
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("stream.udp is not a loopback address")
            && stderr.contains("allow_remote = true")
            && stderr.contains("\"192.168.1.20:9870\""),
        "{stderr}"
    );
}

#[test]
fn nobody_listening_is_counted_and_the_run_goes_on() {
    let _turn = LAB.lock().unwrap_or_else(|e| e.into_inner());
    // A port nobody listens on: bind one, note it, close it.
    let free = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let (stats, _session) = run_lab(&sim_text(&free.to_string(), 100.0), 1.5);
    let streamed = stats.stream.expect("stream stats");
    eprintln!("{streamed:?}");
    assert!(streamed.send_errors > 10, "{streamed:?}");
    assert!(
        stats.frames.tracked > 30 && stats.haptic_loop.ticks > 1000,
        "{stats:?}"
    );
    assert_eq!(stats.safety.faults, 0);
}

/// The reader in docs/stream.md, run as it is printed there.
#[test]
fn the_documented_python_reader_reads_the_stream() {
    let docs =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/stream.md"))
            .unwrap();
    let script = docs
        .split("```python\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("a python block in docs/stream.md");
    let python = match Command::new("python3").arg("--version").output() {
        Ok(out) if out.status.success() => "python3",
        _ => {
            eprintln!("python3 not installed: the documented reader is not run");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("reader.py");
    std::fs::write(&path, script).unwrap();
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    const COUNT: u64 = 40;
    let mut child = Command::new(python)
        .arg(&path)
        .args([port.to_string(), COUNT.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    // The header is printed once the socket is bound.
    let header = lines.next().unwrap().unwrap();
    assert_eq!(
        header,
        "utc,t_s,seq,detected,force_nN,angle_deg,tip_x,tip_y"
    );

    let config = stream::StreamConfig {
        udp: Some(format!("127.0.0.1:{port}").parse().unwrap()),
        haptic_hz: 0.0,
    };
    let shared = Arc::new(StreamShared::default());
    let clock = Clock::start();
    let anchor = UtcAnchor::measure(&clock);
    let mut started = stream::start(&config, shared.clone(), anchor, PixelOrigin::Centre).unwrap();
    for seq in 1..=COUNT {
        let detected = !seq.is_multiple_of(4);
        let estimate = Published {
            probe: 0,
            seq,
            frame_sequence: seq + 100,
            frame_time_s: clock.now_s(),
            published_s: clock.now_s(),
            estimate: Estimate {
                detected,
                angle_deg: detected.then_some(0.01 * seq as f64),
                force_nn: detected.then_some(25.0 * seq as f64),
                apex_px: detected.then_some([300.0, 200.0]),
                confidence: 0.9,
                ..Estimate::default()
            },
        };
        started.estimates.offer(&estimate);
        std::thread::sleep(Duration::from_millis(2));
    }
    let rows: Vec<String> = lines.map(Result::unwrap).collect();
    assert!(child.wait().unwrap().success());
    if let Some(handle) = started.handle.stop() {
        handle.join().unwrap();
    }
    assert_eq!(rows.len() as u64, COUNT, "{rows:?}");
    for (i, row) in rows.iter().enumerate() {
        let seq = i as u64 + 1;
        let cells: Vec<&str> = row.split(',').collect();
        assert_eq!(cells.len(), 8, "{row}");
        parse_utc(cells[0]);
        assert_eq!(cells[2], seq.to_string());
        if !seq.is_multiple_of(4) {
            assert_eq!(cells[3], "True");
            assert_eq!(cells[4].parse::<f64>().unwrap(), 25.0 * seq as f64);
            assert_eq!(cells[6], "300.0");
        } else {
            assert_eq!(&cells[3..], ["False", "", "", "", ""], "{row}");
        }
    }
    assert_eq!(shared.stats().estimates_sent, COUNT);
}
