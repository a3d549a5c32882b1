//! End to end: the built-in simulated lab through the real daemon (threads, tracker,
//! haptic loop, simulated S100, SEM and operator), checked against the daemon issue's
//! targets. Release build, 640x480 at 60 Hz. One test in its own binary, so nothing
//! else competes for the two cores while it runs.
use std::path::Path;
use std::time::Duration;

use nanoforce::cli::run::SIM_CONFIG;
use nanoforce::config::Config;
use nanoforce::daemon::{lab, Daemon, ExitReason, RunOptions};
use nanoforce::hw::Clock;

#[test]
fn simulated_lab_meets_the_force_and_timing_targets() {
    let config = Config::from_toml_str(SIM_CONFIG, Path::new("sim.toml")).unwrap();
    let clock = Clock::start();
    let devices = lab::open(&config, clock).unwrap();
    let session = tempfile::tempdir().unwrap();
    let options = RunOptions {
        // One press to 3 uN and the hold: approach, press, hold, into the retract.
        duration: Some(Duration::from_secs(12)),
        session_dir: Some(session.path().to_path_buf()),
        // SCHED_FIFO and locked memory as the shipped daemon asks; refused (not root, no
        // LimitRTPRIO) they are warnings and the loop runs as an ordinary thread.
        loop_options: config.daemon.loop_options.clone(),
        clock,
        ..RunOptions::default()
    };
    let steal_before = cpu_ticks();
    let outcome = Daemon::start(config.teleop.clone(), devices, options)
        .unwrap()
        .wait()
        .unwrap();
    let steal = steal_fraction(steal_before, cpu_ticks());
    assert_eq!(outcome.exit, ExitReason::Duration);
    let s = outcome.stats;
    eprintln!("{}", serde_json::to_string_pretty(&s).unwrap());

    let peak = s.force.true_peak_nn.unwrap();
    assert!(peak > 2500.0, "the operator pressed to ~3 uN: peak {peak}");
    let rms = s.force.rms_error_nn.unwrap();
    let max = s.force.max_error_nn.unwrap();
    assert!(
        rms <= 0.02 * peak,
        "force rms error {rms} nN > 2 % of {peak}"
    );
    assert!(
        max <= 0.05 * peak,
        "force max error {max} nN > 5 % of {peak}"
    );

    let f = &s.frames;
    assert!(f.received >= 700, "60 Hz for 12 s: {f:?}");
    assert_eq!(f.detected, f.tracked, "the probe is always in view: {f:?}");
    assert_eq!(s.safety.faults, 0);
    assert_eq!(s.safety.stale_events, 0);
    for file in ["ticks.csv", "estimates.csv", "events.log"] {
        let len = std::fs::metadata(session.path().join(file)).unwrap().len();
        assert!(len > 0, "{file} recorded");
    }

    // The timing targets are the daemon's on a machine that is its own. This one is a
    // virtual machine: when the host takes the CPUs away (steal time, /proc/stat), a
    // SCHED_FIFO thread misses its wake-ups by milliseconds whatever it does, so they
    // are checked only when the host left the run alone (docs/performance.md).
    let l = &s.haptic_loop;
    // What must hold however busy the host: the loop keeps its rate on average and its
    // typical period, and the tracker keeps up with most frames.
    assert!(l.rate_hz > 900.0 && l.rate_hz < 1001.0, "{l:?}");
    let p50 = l.period_us_p50.unwrap();
    assert!(
        (990.0..=1010.0).contains(&p50),
        "haptic period p50 {p50} us"
    );
    assert!(f.dropped * 50 <= f.received, "the tracker keeps up: {f:?}");
    eprintln!(
        "host steal {:.1} %, SCHED_FIFO {}",
        steal * 100.0,
        outcome.realtime
    );
    if steal > MAX_STEAL || !outcome.realtime {
        eprintln!("timing targets not checked: the host or the scheduler did not allow them");
        return;
    }
    assert_eq!(f.dropped, 0, "the tracker keeps up: {f:?}");
    assert!(f.latency_ms_p99.unwrap() <= 5.0, "frame latency p99: {f:?}");
    assert!((l.rate_hz - 1000.0).abs() < 5.0, "{l:?}");
    let p99 = l.period_us_p99.unwrap();
    assert!(
        (900.0..=1100.0).contains(&p99),
        "haptic period p99 {p99} us"
    );
}

/// Above this share of CPU time taken by the host, timing is not the daemon's to meet.
const MAX_STEAL: f64 = 0.0025;

/// (steal, total) jiffies of all CPUs so far.
fn cpu_ticks() -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let fields: Vec<u64> = stat
        .lines()
        .next()?
        .split_whitespace()
        .skip(1)
        .map(|v| v.parse().unwrap_or(0))
        .collect();
    let steal = *fields.get(7)?;
    Some((steal, fields.iter().take(8).sum()))
}

/// The share of CPU time the host took between two readings (0 when unknown).
fn steal_fraction(before: Option<(u64, u64)>, after: Option<(u64, u64)>) -> f64 {
    match (before, after) {
        (Some((s0, t0)), Some((s1, t1))) if t1 > t0 => (s1 - s0) as f64 / (t1 - t0) as f64,
        _ => 0.0,
    }
}
