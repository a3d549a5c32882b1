//! Every way `nanoforce run` can end or be disturbed, on the binary with the built-in
//! simulated lab: stop signals, a panic in each thread, a full disk, the recordings
//! budget, a second instance, SIGHUP bursts and changed sections, and the health check
//! right after READY. Each run is a few seconds at most.
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use std::os::unix::process::ExitStatusExt;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

/// A daemon started in the background, its standard error collected as it comes.
struct Running {
    child: Child,
    stderr: Arc<Mutex<String>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Running {
    fn start(args: &[&str], env: &[(&str, &str)]) -> Running {
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .arg("--quiet")
            .args(args)
            .env("RUST_LOG", "info")
            .env_remove("NOTIFY_SOCKET")
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().unwrap();
        let stderr = Arc::new(Mutex::new(String::new()));
        let pipe = child.stderr.take().unwrap();
        let sink = stderr.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                let mut s = sink.lock().unwrap();
                s.push_str(&line);
                s.push('\n');
            }
        });
        Running {
            child,
            stderr,
            reader: Some(reader),
        }
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    fn stderr(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    /// Waits until standard error shows `text` (fails after `limit`).
    fn wait_for(&mut self, text: &str, limit: Duration) {
        let start = Instant::now();
        while !self.stderr().contains(text) {
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!(
                    "exited ({status}) before {text:?}:\n{}",
                    self.finish_reader()
                );
            }
            assert!(
                start.elapsed() < limit,
                "no {text:?} within {limit:?}:\n{}",
                self.stderr()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn signal(&self, sig: libc::c_int) {
        // SAFETY: a signal to our own child.
        assert_eq!(unsafe { libc::kill(self.pid() as libc::pid_t, sig) }, 0);
    }

    /// Waits for the exit (fails after `limit`); the status and all of standard error.
    fn finish(mut self, limit: Duration) -> (ExitStatus, String) {
        let start = Instant::now();
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            if start.elapsed() > limit {
                let _ = self.child.kill();
                panic!("did not exit within {limit:?}:\n{}", self.stderr());
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        (status, self.finish_reader())
    }

    fn finish_reader(&mut self) -> String {
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
        self.stderr()
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn sessions(state: &Path) -> Vec<PathBuf> {
    let mut s: Vec<PathBuf> = std::fs::read_dir(state.join("sessions"))
        .map(|d| d.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    s.sort();
    s
}

fn only_session(state: &Path) -> PathBuf {
    let s = sessions(state);
    assert_eq!(s.len(), 1, "{s:?}");
    s[0].clone()
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&read(path)).unwrap()
}

fn arg(p: &Path) -> &str {
    p.to_str().unwrap()
}

const READY: &str = "nanoforce running";
const START_LIMIT: Duration = Duration::from_secs(20);

#[test]
fn events_and_telemetry_reach_the_disk_during_the_run() {
    let state = tempfile::tempdir().unwrap();
    let mut d = Running::start(&["--state-dir", arg(state.path())], &[]);
    d.wait_for(READY, START_LIMIT);
    std::thread::sleep(Duration::from_millis(2500));
    let session = only_session(state.path());
    // Still running: what is on disk now is what a crash would leave.
    let events = read(&session.join("events.log"));
    assert!(events.contains("state "), "events.log so far: {events:?}");
    d.signal(libc::SIGKILL);
    let _ = d.finish(Duration::from_secs(5));
    let ticks = read(&session.join("ticks.csv"));
    let last_t: f64 = ticks
        .lines()
        .last()
        .and_then(|l| l.split(',').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or(0.0);
    let first_t: f64 = ticks
        .lines()
        .nth(1)
        .and_then(|l| l.split(',').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or(f64::NAN);
    // Killed 2.5 s after READY: at most about a second of ticks is lost.
    assert!(
        last_t - first_t > 1.2,
        "ticks.csv covers {first_t}..{last_t} s"
    );
    assert!(read(&session.join("estimates.csv")).lines().count() > 5);
}

#[test]
fn stop_signals_zero_the_outputs_and_record_the_stop() {
    for (sig, name) in [
        (libc::SIGABRT, "SIGABRT"),
        (libc::SIGQUIT, "SIGQUIT"),
        (libc::SIGUSR1, "SIGUSR1"),
        (libc::SIGUSR2, "SIGUSR2"),
        (libc::SIGALRM, "SIGALRM"),
        (libc::SIGXCPU, "SIGXCPU"),
    ] {
        let state = tempfile::tempdir().unwrap();
        let stats = state.path().join("stats-out.json");
        let mut d = Running::start(
            &[
                "--state-dir",
                arg(state.path()),
                "--stats-json",
                arg(&stats),
            ],
            &[],
        );
        d.wait_for(READY, START_LIMIT);
        std::thread::sleep(Duration::from_millis(300));
        d.signal(sig);
        let (status, err) = d.finish(Duration::from_secs(5));
        assert_eq!(status.signal(), None, "{name}: killed by the signal\n{err}");
        assert_eq!(status.code(), Some(128 + sig), "{name}\n{err}");
        assert!(
            err.contains(&format!("{name}: stopping with outputs at zero")),
            "{err}"
        );
        let session = only_session(state.path());
        let events = read(&session.join("events.log"));
        let last = events.lines().last().unwrap_or("");
        assert_eq!(
            last,
            format!("stop: {name}; outputs at zero, forces off"),
            "{name}: {events}"
        );
        for path in [session.join("stats.json"), stats.clone()] {
            let s = json(&path);
            assert_eq!(s["stop"]["reason"], name, "{}", path.display());
            assert_eq!(s["stop"]["outputs_zeroed"], true);
            assert!(s["haptic_loop"]["ticks"].as_u64().unwrap() > 100);
        }
    }
}

#[test]
fn a_panic_in_any_thread_zeroes_the_outputs_and_records_the_stop() {
    for thread in nanoforce::daemon::inject::THREADS {
        let state = tempfile::tempdir().unwrap();
        let stats = state.path().join("stats-out.json");
        let d = Running::start(
            &[
                "--duration-s",
                "10",
                "--state-dir",
                arg(state.path()),
                "--stats-json",
                arg(&stats),
            ],
            &[("NANOFORCE_INJECT_PANIC", &format!("{thread}@0.3"))],
        );
        let (status, err) = d.finish(Duration::from_secs(25));
        assert_eq!(status.code(), Some(70), "{thread}:\n{err}");
        assert!(
            err.contains(&format!("injected panic in the {thread} thread")),
            "{err}"
        );
        let reason = format!("panic in the {thread} thread");
        let session = only_session(state.path());
        let events = read(&session.join("events.log"));
        let stop = events
            .lines()
            .find(|l| l.starts_with("stop: "))
            .unwrap_or_else(|| panic!("{thread}: no stop in events.log: {events}"));
        assert!(
            stop.starts_with(&format!("stop: {reason}"))
                && stop.ends_with("outputs at zero, forces off"),
            "{stop}"
        );
        let s = json(&stats);
        assert_eq!(s["stop"]["reason"], reason.as_str());
        assert_eq!(s["stop"]["outputs_zeroed"], true, "{thread}");
        assert_eq!(
            json(&session.join("stats.json"))["stop"]["reason"],
            reason.as_str()
        );
    }
}

/// Mounts a tmpfs of `size` on `dir`; None (with the reason printed) when not permitted.
fn mount_tmpfs(dir: &Path, size: &str) -> Option<()> {
    let out = Command::new("mount")
        .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
        .arg(dir)
        .output();
    match out {
        Ok(o) if o.status.success() => Some(()),
        Ok(o) => {
            eprintln!(
                "skipped: mounting a tmpfs is not permitted here ({})",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            None
        }
        Err(e) => {
            eprintln!("skipped: cannot run mount ({e})");
            None
        }
    }
}

struct Unmount(PathBuf);

impl Drop for Unmount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// Fills the file system holding `dir` until a write fails.
fn fill(dir: &Path) {
    use std::io::Write;
    let mut f = std::fs::File::create(dir.join("filler")).unwrap();
    let block = vec![0u8; 4096];
    while f.write_all(&block).and_then(|_| f.flush()).is_ok() {}
}

#[test]
fn a_full_disk_stops_the_recording_not_the_control() {
    let root = tempfile::tempdir().unwrap();
    let state = root.path().join("state");
    std::fs::create_dir(&state).unwrap();
    if mount_tmpfs(&state, "256k").is_none() {
        return;
    }
    let _unmount = Unmount(state.clone());
    let stats = root.path().join("stats.json");
    let notify_path = root.path().join("notify.sock");
    let notify = std::os::unix::net::UnixDatagram::bind(&notify_path).unwrap();
    notify
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let mut d = Running::start(
        &[
            "--duration-s",
            "3",
            "--state-dir",
            arg(&state),
            "--stats-json",
            arg(&stats),
        ],
        &[("NOTIFY_SOCKET", arg(&notify_path))],
    );
    d.wait_for(READY, START_LIMIT);
    std::thread::sleep(Duration::from_millis(500));
    fill(&state);
    d.wait_for("recording stopped", Duration::from_secs(3));
    // The status systemd shows says so.
    let mut statuses = String::new();
    let deadline = Instant::now() + Duration::from_secs(3);
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline && !statuses.contains("recording stopped") {
        if let Ok(n) = notify.recv(&mut buf) {
            statuses.push_str(&String::from_utf8_lossy(&buf[..n]));
            statuses.push('\n');
        }
    }
    let (status, err) = d.finish(Duration::from_secs(10));
    assert!(
        statuses.contains("STATUS=") && statuses.contains("recording stopped"),
        "{statuses}"
    );
    assert!(err.contains("No space left on device"), "{err}");
    assert_eq!(status.code(), Some(74), "{err}");
    let s = json(&stats);
    assert_eq!(s["recording"]["state"], "stopped");
    assert!(s["recording"]["error"]
        .as_str()
        .unwrap()
        .contains("No space left on device"));
    // Control went on for the whole run.
    assert_eq!(s["stop"]["reason"], "duration");
    assert!(s["haptic_loop"]["ticks"].as_u64().unwrap() > 2000, "{s}");
}

#[test]
fn the_recordings_budget_deletes_the_oldest_sessions() {
    let state = tempfile::tempdir().unwrap();
    let sessions_dir = state.path().join("sessions");
    // Four old sessions of 600 KiB each, and a folder that is not a session.
    let old = [
        "20240101T000000Z-11",
        "20240102T000000Z-12",
        "20240103T000000Z-13",
        "20240104T000000Z-14",
    ];
    for name in old {
        let dir = sessions_dir.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("ticks.csv"), vec![b'0'; 600 * 1024]).unwrap();
    }
    std::fs::create_dir_all(sessions_dir.join("keep-me")).unwrap();
    let config = state.path().join("lab.toml");
    let sim = read(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/sim.toml"
    )));
    std::fs::write(
        &config,
        sim.replace("[daemon]\n", "[daemon]\nrecordings_max_mb = 1\n"),
    )
    .unwrap();
    let d = Running::start(
        &[
            "--config",
            arg(&config),
            "--duration-s",
            "1",
            "--state-dir",
            arg(state.path()),
        ],
        &[],
    );
    let (status, err) = d.finish(Duration::from_secs(25));
    assert!(status.success(), "{err}");
    let left: Vec<String> = sessions(state.path())
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    // 2.4 MiB of old sessions against 1 MiB: the three oldest go, each logged.
    assert!(
        !left
            .iter()
            .any(|n| n.as_str() < old[3] && n.starts_with("2024")),
        "{left:?}"
    );
    assert!(left.contains(&old[3].to_string()), "{left:?}");
    assert!(left.contains(&"keep-me".to_string()), "{left:?}");
    assert_eq!(left.len(), 3, "{left:?}");
    for name in &old[..3] {
        assert!(
            err.contains("deleted the oldest session") && err.contains(name),
            "{err}"
        );
    }
}

#[test]
fn a_second_daemon_on_the_same_state_directory_is_refused() {
    let state = tempfile::tempdir().unwrap();
    let mut first = Running::start(&["--state-dir", arg(state.path())], &[]);
    first.wait_for(READY, START_LIMIT);
    let second = Running::start(
        &["--duration-s", "1", "--state-dir", arg(state.path())],
        &[],
    );
    let (status, err) = second.finish(Duration::from_secs(10));
    assert_eq!(status.code(), Some(1), "{err}");
    assert!(
        err.contains("in use by another nanoforce run")
            && err.contains(&format!("pid {}", first.pid())),
        "{err}"
    );
    assert!(!err.contains(READY), "{err}");
    // A crash leaves no stale lock.
    first.signal(libc::SIGKILL);
    let _ = first.finish(Duration::from_secs(5));
    let third = Running::start(
        &["--duration-s", "0.5", "--state-dir", arg(state.path())],
        &[],
    );
    let (status, err) = third.finish(Duration::from_secs(20));
    assert!(status.success(), "{err}");
}

fn config_with(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
    let sim = read(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/sim.toml"
    )));
    assert!(sim.contains(from), "config/sim.toml has no {from:?}");
    let path = dir.join(name);
    std::fs::write(&path, sim.replacen(from, to, 1)).unwrap();
    path
}

#[test]
fn sighup_names_sections_that_need_a_restart_and_a_burst_is_no_stall() {
    let dir = tempfile::tempdir().unwrap();
    let config = config_with(
        dir.path(),
        "lab.toml",
        "length_um = 434.675",
        "length_um = 434.675",
    );
    let mut d = Running::start(
        &["--config", arg(&config), "--no-record", "--duration-s", "8"],
        &[],
    );
    d.wait_for(READY, START_LIMIT);
    // A burst of reloads of an unchanged file.
    for _ in 0..30 {
        d.signal(libc::SIGHUP);
        std::thread::sleep(Duration::from_millis(2));
    }
    d.wait_for("gains reloaded", Duration::from_secs(3));
    std::thread::sleep(Duration::from_millis(500));
    // Now a changed [cantilever] and [tracker].
    let text = read(&config)
        .replacen("length_um = 434.675", "length_um = 440.0", 1)
        .replacen("window_deg = 20.0", "window_deg = 22.0", 1);
    std::fs::write(&config, text).unwrap();
    d.signal(libc::SIGHUP);
    d.wait_for("need a restart", Duration::from_secs(3));
    d.signal(libc::SIGTERM);
    let (status, err) = d.finish(Duration::from_secs(5));
    assert!(status.success(), "{err}");
    assert!(!err.contains("stalled"), "{err}");
    let warning = err
        .lines()
        .find(|l| l.contains("SIGHUP") && l.contains("need a restart"))
        .unwrap_or_else(|| panic!("no restart warning:\n{err}"));
    assert!(
        warning.contains("WARN")
            && warning.contains("[cantilever]")
            && warning.contains("[tracker]"),
        "{warning}"
    );
    assert!(!warning.contains("[teleop]:"), "{warning}");
}

#[test]
fn no_stall_warning_right_after_ready() {
    for run in 0..5 {
        let d = Running::start(&["--no-record", "--duration-s", "0.6"], &[]);
        let (status, err) = d.finish(Duration::from_secs(25));
        assert!(status.success(), "run {run}: {err}");
        assert!(err.contains(READY), "{err}");
        assert!(!err.contains("unhealthy"), "run {run}:\n{err}");
    }
}
