//! `nanoforce run`: the real-time teleoperation daemon. Without `--config` it runs the
//! built-in simulated lab (config/sim.toml, compiled in), so it works anywhere.
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Args;

use crate::config::{Config, Number, ProbeConfig};
use crate::daemon::inject::PanicInjection;
use crate::daemon::instance::{self, InstanceLock};
use crate::daemon::notify::Notifier;
use crate::daemon::{lab, telemetry, Daemon, ExitReason, Reload, RunOptions};
use crate::hw::Clock;

/// The built-in simulated lab.
pub const SIM_CONFIG: &str = include_str!("../../config/sim.toml");

/// `--duration-s` accepted, seconds: from one millisecond to about 11.6 days (a longer
/// run is started without it and stopped by a signal). Far larger values overflow the
/// clock's deadline.
const DURATION_S: (f64, f64) = (0.001, 1e6);

/// Run the real-time teleoperation daemon (default: the built-in simulated lab).
#[derive(Debug, Args)]
#[command(
    long_about = "Runs the real-time teleoperation daemon.\n\n\
Threads: frames (the SEM source) -> tracker (tip angle and force) -> the 1 kHz haptic \
loop, which reads the stylus, renders the scaled force on top of centring springs and \
sends the S100 its rate command. Without --config the built-in simulated lab runs \
(simulated S100, sample, SEM and operator; see config/sim.toml).\n\n\
Several probes ([[probe]] entries, config/probe.example.toml): each rides its own S100 \
positioner and is tracked in every frame; the stylus drives and feels one at a time, and \
its second button switches to the next (motion waits for the re-centred stylus). \
config/sim-two-probes.toml is the simulated lab of two; config/sim-needle.toml puts a \
rigid needle (tracked, no force) beside the cantilever.\n\n\
Signals: SIGINT or SIGTERM stop cleanly with the outputs at zero; SIGQUIT, SIGABRT \
(systemd's watchdog), SIGUSR1, SIGUSR2, SIGALRM and SIGXCPU stop the same way and exit \
with 128 + the signal's number. SIGHUP reloads the [teleop] and [safety] gains from the \
config file (an invalid file is rejected and the old gains kept; other changed sections \
are named as needing a restart).\n\n\
One run per state directory and device: a second is refused, naming the first one's \
pid. Exit status: 0 a clean stop, 1 refused to start, 70 a thread panicked, 74 the \
recording failed (a full disk) while control went on, 128 + n a stop signal n.\n\n\
Under systemd (Type=notify) it reports READY, STATUS and WATCHDOG.\n\n\
Every run records its telemetry (ticks.csv, estimates.csv or estimates.<name>.csv per \
probe, events.log, config.toml, stats.json) in a session folder under the state \
directory.",
    after_help = "Examples:\n  nanoforce run                                  # the simulated lab\n  \
nanoforce run --duration-s 30 --stats-json stats.json\n  \
nanoforce run --config config/sim-two-probes.toml  # two probes, two positioners\n  \
nanoforce run --config config/sim-needle.toml      # a cantilever beside a needle\n  \
nanoforce run --config /etc/nanoforce/nanoforce.toml"
)]
pub struct RunArgs {
    /// Lab configuration (TOML); default: the built-in simulated lab.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Stop after this many seconds (default: run until SIGINT/SIGTERM).
    #[arg(
        long,
        value_name = "SECONDS",
        value_parser = parse_duration_s,
        allow_negative_numbers = true
    )]
    pub duration_s: Option<f64>,
    /// Write the run's statistics (loop timing, frames, force error, safety) as JSON.
    #[arg(long, value_name = "PATH")]
    pub stats_json: Option<PathBuf>,
    /// Record sessions under this directory (default: $STATE_DIRECTORY, else
    /// [daemon] state_dir, else ~/.local/state/nanoforce).
    #[arg(long, value_name = "DIR")]
    pub state_dir: Option<PathBuf>,
    /// Do not record a session folder.
    #[arg(long)]
    pub no_record: bool,
    /// No live status line on the terminal.
    #[arg(long)]
    pub quiet: bool,
}

/// Exit statuses besides 0 (a clean stop) and 1 (refused to start: an invalid
/// configuration, a device that would not open, another run holding the devices).
pub mod exit_status {
    /// A thread of the daemon panicked (outputs were zeroed).
    pub const THREAD_FAILED: u8 = 70;
    /// The run went on but its recording did not (a full disk, a write error, the budget)
    /// or a stats file could not be written.
    pub const RECORDING_FAILED: u8 = 74;
    /// A stop signal other than SIGINT/SIGTERM ended the run: 128 + its number.
    pub const SIGNAL_BASE: u8 = 128;
}

pub fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    // The configuration is validated completely before any device is opened.
    let (config, text) = load(args.config.as_deref())?;
    let duration = args
        .duration_s
        .map(|s| check_duration_s(s).map(Duration::from_secs_f64))
        .transpose()
        .map_err(|e| anyhow::anyhow!("--duration-s {e}"))?;
    // Opened now, so that an unwritable path is refused before anything moves.
    let stats_json = args
        .stats_json
        .as_deref()
        .map(StatsFile::open)
        .transpose()?;
    let inject = PanicInjection::from_env().map_err(anyhow::Error::msg)?;
    let state_dir = (!args.no_record).then(|| {
        args.state_dir
            .clone()
            .or_else(|| {
                std::env::var_os("STATE_DIRECTORY")
                    .is_none()
                    .then(|| config.daemon.state_dir.clone())
                    .flatten()
            })
            .unwrap_or_else(telemetry::default_state_dir)
    });
    // One daemon per state directory and per device, before anything is opened.
    if let Some(dir) = &state_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let _lock = InstanceLock::acquire(&instance::targets(state_dir.as_deref(), &config.devices))?;
    let budget = state_dir.as_ref().map(|dir| telemetry::Budget {
        sessions_dir: dir.join("sessions"),
        max_bytes: config.daemon.recordings_max_mb * 1024 * 1024,
    });
    if let Some(budget) = &budget {
        telemetry::prune_sessions(budget, None);
    }
    let clock = Clock::start();
    let devices = lab::open(&config, clock).context("opening the lab's devices")?;
    let (session_dir, recording_error) = match &state_dir {
        None => (None, None),
        Some(state_dir) => match new_session(state_dir, &text) {
            Ok(dir) => {
                tracing::info!("recording this session in {}", dir.display());
                (Some(dir), None)
            }
            // A full disk does not stop the lab: the run goes on unrecorded, and says so.
            Err(e) => {
                let reason = format!("{e:#}");
                tracing::warn!("not recording: {reason}");
                (None, Some(reason))
            }
        },
    };
    let reload_path = args.config.clone();
    let running = config.clone();
    let options = RunOptions {
        duration,
        session_dir: session_dir.clone(),
        config_file: args
            .config
            .as_deref()
            .map(std::path::absolute)
            .transpose()?,
        status_line: !args.quiet,
        handle_signals: true,
        reload: reload_path.map(|path| {
            Box::new(move || {
                let new = Config::load(&path)?;
                Ok(Reload {
                    needs_restart: restart_sections(&running, &new),
                    gains: new.teleop,
                })
            }) as Box<dyn Fn() -> anyhow::Result<Reload> + Send>
        }),
        loop_options: config.daemon.loop_options.clone(),
        notifier: Notifier::from_env().context("connecting to systemd's NOTIFY_SOCKET")?,
        stop_when_frames_end: false,
        clock,
        monitor: Some(config.monitor.clone()),
        pixel_origin: config.probes[0].tracker.pixel_origin,
        recordings_budget: budget,
        recording_error,
        stream: config.stream.clone(),
        inject,
    };
    let handle = Daemon::start(config.teleop.clone(), devices, options)?;
    let outcome = handle.wait()?;
    let json = serde_json::to_string_pretty(&outcome.stats)?;
    let mut write_failed = false;
    if let Some(dir) = &session_dir {
        let path = dir.join("stats.json");
        if let Err(e) = std::fs::write(&path, &json) {
            tracing::warn!("writing {}: {e}", path.display());
            write_failed = true;
        }
    }
    if let Some(file) = stats_json {
        if let Err(e) = file.write(&json) {
            tracing::error!("{e:#}");
            write_failed = true;
        }
    }
    summarise(&outcome.stats);
    let recording_failed = outcome.stats.recording.state == "stopped";
    Ok(match outcome.exit {
        ExitReason::ThreadFailed(name) => {
            tracing::error!("the {name} thread failed; outputs were set to zero");
            ExitCode::from(exit_status::THREAD_FAILED)
        }
        ExitReason::Signal(name) if !matches!(name, "SIGINT" | "SIGTERM") => {
            let number = outcome.exit.signal_number().unwrap_or(0);
            tracing::warn!("stopped by {name}; outputs were set to zero");
            ExitCode::from(exit_status::SIGNAL_BASE + number as u8)
        }
        _ if recording_failed || write_failed => {
            let what = outcome
                .stats
                .recording
                .error
                .as_deref()
                .unwrap_or("a stats file could not be written");
            tracing::error!("the run went on but its recording failed: {what}");
            ExitCode::from(exit_status::RECORDING_FAILED)
        }
        _ => ExitCode::SUCCESS,
    })
}

/// `--duration-s`'s value parser: a clear usage error for a value out of range.
fn parse_duration_s(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    check_duration_s(seconds)
}

fn check_duration_s(seconds: f64) -> Result<f64, String> {
    let (lo, hi) = DURATION_S;
    if seconds.is_finite() && (lo..=hi).contains(&seconds) {
        Ok(seconds)
    } else {
        Err(format!(
            "{} is out of range: accepted {} to {} s (without it the run lasts until stopped)",
            Number(seconds),
            Number(lo),
            Number(hi)
        ))
    }
}

/// The `--stats-json` file, opened before the run; a file it created is removed again
/// if the run ends before writing it.
struct StatsFile {
    path: PathBuf,
    file: File,
    created: bool,
    written: bool,
}

impl StatsFile {
    fn open(path: &Path) -> anyhow::Result<StatsFile> {
        let created = std::fs::symlink_metadata(path).is_err();
        let file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .with_context(|| format!("--stats-json {}: cannot write there", path.display()))?;
        Ok(StatsFile {
            path: path.to_path_buf(),
            file,
            created,
            written: false,
        })
    }

    fn write(mut self, json: &str) -> anyhow::Result<()> {
        // A regular file loses what an earlier run left; a pipe or terminal
        // (`/dev/stdout`) cannot be truncated and need not be.
        let regular = self.file.metadata().is_ok_and(|m| m.is_file());
        let truncate = if regular {
            self.file.set_len(0)
        } else {
            Ok(())
        };
        truncate
            .and_then(|()| self.file.write_all(json.as_bytes()))
            .with_context(|| format!("writing {}", self.path.display()))?;
        self.written = true;
        Ok(())
    }
}

impl Drop for StatsFile {
    fn drop(&mut self) {
        if self.created && !self.written {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// A new session folder holding the configuration the run uses.
fn new_session(state_dir: &Path, text: &str) -> anyhow::Result<PathBuf> {
    let dir = telemetry::create_session_dir(state_dir)
        .with_context(|| format!("creating a session folder under {}", state_dir.display()))?;
    let path = dir.join("config.toml");
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    Ok(dir)
}

/// The sections SIGHUP cannot apply that differ between the running and the new file.
fn restart_sections(running: &Config, new: &Config) -> Vec<&'static str> {
    let mut changed = Vec::new();
    let mut check = |name, same: bool| {
        if !same {
            changed.push(name);
        }
    };
    let (was, now) = (&running.probes, &new.probes);
    // A probe's name, whether it is felt, its pressing sign and its simulated place.
    let entry = |p: &ProbeConfig| (p.name.clone(), p.felt, p.pressing_force_sign, p.sim.clone());
    check("probe", was.iter().map(entry).eq(now.iter().map(entry)));
    check(
        "cantilever",
        was.iter()
            .map(|p| p.cantilever)
            .eq(now.iter().map(|p| p.cantilever)),
    );
    check(
        "tracker",
        was.iter()
            .map(|p| &p.tracker)
            .eq(now.iter().map(|p| &p.tracker)),
    );
    check("frames", running.devices.frames == new.devices.frames);
    check(
        "daq",
        running.devices.positioners == new.devices.positioners,
    );
    check("haptic", running.devices.haptic == new.devices.haptic);
    check("daemon", running.daemon == new.daemon);
    check("monitor", running.monitor == new.monitor);
    check("stream", running.stream == new.stream);
    check("sim", running.sim == new.sim);
    changed
}

/// The configuration and its text (recorded with the session).
fn load(path: Option<&Path>) -> anyhow::Result<(Config, String)> {
    match path {
        Some(path) => {
            let config = Config::load(path)?;
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            Ok((config, text))
        }
        None => {
            let config = Config::from_toml_str(SIM_CONFIG, Path::new("<built-in sim.toml>"))?;
            Ok((config, SIM_CONFIG.to_string()))
        }
    }
}

/// Below this true peak (nN) the run summary gives force errors without a share of it.
const MIN_PEAK_FOR_SHARE_NN: f64 = 10.0;

/// A probe's force error against the simulator's truth, when there is one.
fn force_summary(force: &crate::daemon::stats::ForceStats) -> Option<String> {
    let (Some(peak), Some(rms), Some(max)) =
        (force.true_peak_nn, force.rms_error_nn, force.max_error_nn)
    else {
        return None;
    };
    // A share of a peak means something only once the probe pressed.
    Some(if peak >= MIN_PEAK_FOR_SHARE_NN {
        format!(
            "peak {peak:.0} nN, rms error {rms:.1} nN ({:.2} %), max error {max:.1} nN ({:.2} %)",
            100.0 * rms / peak,
            100.0 * max / peak
        )
    } else {
        format!("no press (peak {peak:.1} nN), rms error {rms:.1} nN, max error {max:.1} nN")
    })
}

fn summarise(stats: &crate::daemon::stats::RunStats) {
    let l = &stats.haptic_loop;
    let f = &stats.frames;
    let opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.1}"));
    tracing::info!(
        "ran {:.1} s: haptic loop {:.1} Hz (period p50 {} us, p99 {} us, max {} us, {} overruns); \
         frames {} received, {} tracked, {} detected, {} dropped, latency p50 {} ms p99 {} ms",
        stats.duration_s,
        l.rate_hz,
        opt(l.period_us_p50),
        opt(l.period_us_p99),
        opt(l.period_us_max),
        l.overruns,
        f.received,
        f.tracked,
        f.detected,
        f.dropped,
        opt(f.latency_ms_p50),
        opt(f.latency_ms_p99),
    );
    match stats.probes.as_slice() {
        [_, _, ..] => {
            for p in &stats.probes {
                tracing::info!(
                    "probe {}: detected in {} frames{}",
                    p.name,
                    p.frames.detected,
                    force_summary(&p.force)
                        .map(|s| format!("; force against the simulated truth: {s}"))
                        .unwrap_or_default()
                );
            }
        }
        _ => {
            if let Some(s) = force_summary(&stats.force) {
                tracing::info!("force against the simulated truth: {s}");
            }
        }
    }
    tracing::info!(
        "safety: {} stale events, {} faults, {} estimates held and {} attenuated by the \
         plausibility gate",
        stats.safety.stale_events,
        stats.safety.faults,
        stats.safety.gate_held,
        stats.safety.gate_attenuated
    );
    let m = &stats.memory;
    if let (Some(warm), Some(end)) = (m.rss_mb_after_warmup, m.rss_mb_end) {
        tracing::info!(
            "memory: {warm:.1} MiB resident after warm-up, {end:.1} MiB at the end ({:+.2} MiB)",
            end - warm
        );
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_file_replaces_old_content_and_leaves_nothing_when_unwritten() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("stats.json");
        std::fs::write(&path, "x".repeat(10_000)).unwrap();
        StatsFile::open(&path).unwrap().write("{}").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{}");
        // Kept when it was there before, removed when only this run created it.
        drop(StatsFile::open(&path).unwrap());
        assert!(path.exists());
        let fresh = dir.path().join("fresh.json");
        drop(StatsFile::open(&fresh).unwrap());
        assert!(!fresh.exists());
    }

    #[test]
    fn duration_range() {
        assert_eq!(parse_duration_s("2.5"), Ok(2.5));
        assert_eq!(parse_duration_s("1e6"), Ok(1e6));
        for bad in ["1e19", "0", "-3", "nan", "inf"] {
            let msg = parse_duration_s(bad).unwrap_err();
            assert!(
                msg.ends_with(
                    "accepted 0.001 to 1000000 s (without it the run lasts until stopped)"
                ),
                "{msg}"
            );
        }
        assert!(parse_duration_s("soon")
            .unwrap_err()
            .contains("not a number"));
    }
}
