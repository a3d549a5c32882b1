//! The supervisor: starts the loops, watches them, talks to systemd, handles signals,
//! and on the way out makes sure the outputs are at zero before it reports.
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc as async_mpsc;

use super::haptic_loop::{FeltProbe, GateLog, LoopOptions, LoopShared};
use super::inject::PanicInjection;
use super::monitor::MonitorConfig;
use super::notify::Notifier;
use super::pipeline::{Estimator, PipelineShared};
use super::recording::RecordingStatus;
use super::stats::{MemoryWatch, RunStats, StopStats};
use super::stream::StreamConfig;
use super::telemetry::Budget;
use crate::config::PixelOrigin;
use crate::control::{SafetyState, TeleopGains};
use crate::hw::daq::RateOutput;
use crate::hw::frames::FrameSource;
use crate::hw::haptic::HapticDevice;
use crate::hw::Clock;
use crate::vision::SINGLE_NAME;
use health::Health;
use report::{assemble_stats, recording_stats};
use signals::{SignalEvent, Signals};
use threads::{dead_thread, spawn_threads, Threads};

mod health;
mod report;
mod signals;
mod threads;

/// The opened devices and the tracker, ready to run.
pub struct Devices {
    pub frames: Box<dyn FrameSource>,
    /// Tracks every probe in view.
    pub estimator: Box<dyn Estimator>,
    /// Each probe's positioner, in the probes' order.
    pub stages: Vec<Box<dyn RateOutput>>,
    pub haptic: Box<dyn HapticDevice>,
    /// Each probe's name, in order.
    pub names: Vec<String>,
    /// The probes the stylus can feel, in switching order (the first at the start).
    pub felt: Vec<FeltProbe>,
}

impl Devices {
    /// One probe, on `stage`, felt with `[teleop]` as it is.
    pub fn one_probe(
        frames: Box<dyn FrameSource>,
        estimator: Box<dyn Estimator>,
        stage: Box<dyn RateOutput>,
        haptic: Box<dyn HapticDevice>,
    ) -> Devices {
        Devices {
            frames,
            estimator,
            stages: vec![stage],
            haptic,
            names: vec![SINGLE_NAME.to_string()],
            felt: vec![FeltProbe::SINGLE],
        }
    }
}

/// How to run.
pub struct RunOptions {
    /// Stop after this long (None: until a signal or a stop request).
    pub duration: Option<Duration>,
    /// Record telemetry into this session folder.
    pub session_dir: Option<PathBuf>,
    /// The configuration file the run loaded (absolute; None: built in), named in the
    /// session's `session.json`.
    pub config_file: Option<PathBuf>,
    /// Print a live status line on standard error.
    pub status_line: bool,
    /// Handle SIGINT/SIGTERM (stop) and SIGHUP (reload gains through `reload`).
    pub handle_signals: bool,
    /// Reads and validates new gains for SIGHUP; an error keeps the old gains.
    pub reload: Option<Box<dyn Fn() -> anyhow::Result<Reload> + Send>>,
    pub loop_options: LoopOptions,
    pub notifier: Notifier,
    /// Stop when the frame source ends (a finite recording).
    pub stop_when_frames_end: bool,
    /// The clock the frame source stamps frames with; the loops use the same one.
    pub clock: Clock,
    /// The live page and the recorded thumbnails (`[monitor]`); None: neither.
    pub monitor: Option<MonitorConfig>,
    /// `tracker.pixel_origin`: where the recorded apex columns count from.
    pub pixel_origin: PixelOrigin,
    /// `[daemon] recordings_max_mb`: the running session keeps the recordings below it.
    pub recordings_budget: Option<Budget>,
    /// Why there is no session folder although one was asked for (a full disk at start).
    pub recording_error: Option<String>,
    /// `[stream]`: the live UDP data stream (off unless its `udp` is set).
    pub stream: StreamConfig,
    /// A panic to inject (tests only; None in every normal run).
    pub inject: Option<PanicInjection>,
}

/// What SIGHUP read from the configuration file.
pub struct Reload {
    /// `[teleop]` and `[safety]`, handed to the haptic loop.
    pub gains: TeleopGains,
    /// Sections that changed but are only read at start (`"cantilever"`, `"tracker"`,
    /// ...): the run goes on with their old values and says they need a restart.
    pub needs_restart: Vec<&'static str>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: None,
            session_dir: None,
            config_file: None,
            status_line: false,
            handle_signals: false,
            reload: None,
            loop_options: LoopOptions::default(),
            notifier: Notifier::disabled(),
            stop_when_frames_end: false,
            clock: Clock::start(),
            monitor: None,
            pixel_origin: PixelOrigin::Centre,
            recordings_budget: None,
            recording_error: None,
            stream: StreamConfig::default(),
            inject: None,
        }
    }
}

/// Why the run ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ExitReason {
    Duration,
    /// A stop signal, by name ("SIGTERM", "SIGABRT", ...).
    Signal(&'static str),
    Requested,
    FramesEnded,
    /// A thread died (panicked): the outputs were zeroed, the run is a failure.
    ThreadFailed(String),
}

impl ExitReason {
    /// As `stats.json` and `events.log` say it.
    pub fn describe(&self) -> String {
        match self {
            ExitReason::Duration => "duration".into(),
            ExitReason::Signal(name) => (*name).into(),
            ExitReason::Requested => "requested".into(),
            ExitReason::FramesEnded => "frames ended".into(),
            ExitReason::ThreadFailed(name) => format!("panic in the {name} thread"),
        }
    }

    /// The number of a stop signal (SIGABRT: 6), for the exit status 128 + n.
    pub fn signal_number(&self) -> Option<i32> {
        match self {
            ExitReason::Signal(name) => STOP_SIGNALS
                .iter()
                .find(|(_, n)| n == name)
                .map(|(number, _)| *number),
            _ => None,
        }
    }
}

/// The signals that stop the daemon (outputs to zero, the stop recorded, then exit).
/// SIGINT and SIGTERM are the normal stop; the others mean something went wrong
/// (SIGABRT: systemd's watchdog; SIGXCPU: a CPU-time limit) and end with 128 + n.
pub const STOP_SIGNALS: [(i32, &str); 8] = [
    (libc::SIGINT, "SIGINT"),
    (libc::SIGTERM, "SIGTERM"),
    (libc::SIGQUIT, "SIGQUIT"),
    (libc::SIGABRT, "SIGABRT"),
    (libc::SIGUSR1, "SIGUSR1"),
    (libc::SIGUSR2, "SIGUSR2"),
    (libc::SIGALRM, "SIGALRM"),
    (libc::SIGXCPU, "SIGXCPU"),
];

#[derive(Debug, Clone)]
pub struct Outcome {
    pub stats: RunStats,
    pub exit: ExitReason,
    pub realtime: bool,
}

enum Command {
    Stop,
    Reload(Box<TeleopGains>),
}

/// A running daemon.
pub struct DaemonHandle {
    commands: async_mpsc::UnboundedSender<Command>,
    supervisor: JoinHandle<anyhow::Result<Outcome>>,
    pub loop_shared: Arc<LoopShared>,
    pub pipeline_shared: Arc<PipelineShared>,
    /// Where the monitor page is served, when it is.
    pub monitor_addr: Option<SocketAddr>,
    /// Whether the session is being recorded.
    pub recording: Arc<RecordingStatus>,
}

impl DaemonHandle {
    pub fn stop(&self) {
        let _ = self.commands.send(Command::Stop);
    }

    /// New gains, as SIGHUP would load them.
    pub fn reload(&self, gains: TeleopGains) {
        let _ = self.commands.send(Command::Reload(Box::new(gains)));
    }

    /// Waits for the run to end.
    pub fn wait(self) -> anyhow::Result<Outcome> {
        match self.supervisor.join() {
            Ok(result) => result,
            Err(_) => anyhow::bail!("the supervisor thread panicked"),
        }
    }
}

pub struct Daemon;

impl Daemon {
    /// Starts every thread; the devices must already be open (an invalid configuration
    /// is rejected before this point, so nothing was opened for it).
    pub fn start(
        gains: TeleopGains,
        devices: Devices,
        options: RunOptions,
    ) -> anyhow::Result<DaemonHandle> {
        let clock = options.clock;
        let loop_shared = Arc::new(LoopShared::default());
        let pipeline_shared = Arc::new(PipelineShared::default());
        let (commands, commands_rx) = async_mpsc::unbounded_channel();
        let recording = Arc::new(match (&options.session_dir, &options.recording_error) {
            (Some(_), _) => RecordingStatus::recording(),
            (None, Some(error)) => {
                let status = RecordingStatus::default();
                status.stop(error.clone());
                status
            }
            (None, None) => RecordingStatus::default(),
        });
        let mut threads = spawn_threads(
            gains,
            devices,
            &options,
            clock,
            loop_shared.clone(),
            pipeline_shared.clone(),
            recording.clone(),
        )?;
        let monitor_addr = threads.monitor.as_mut().and_then(|m| m.local_addr);
        let supervisor = {
            let loop_shared = loop_shared.clone();
            let pipeline_shared = pipeline_shared.clone();
            let recording = recording.clone();
            thread::Builder::new()
                .name("supervisor".into())
                .spawn(move || {
                    let runtime = tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                        .context("starting the supervisor's runtime")?;
                    let started = Instant::now();
                    let zeroed = threads.outputs_zeroed.clone();
                    let probe_names = threads.probe_names.clone();
                    let run = std::panic::AssertUnwindSafe(|| {
                        runtime.block_on(supervise(
                            options,
                            threads,
                            commands_rx,
                            loop_shared.clone(),
                            pipeline_shared.clone(),
                            recording.clone(),
                        ))
                    });
                    match std::panic::catch_unwind(run) {
                        Ok(outcome) => outcome,
                        // The threads were stopped, outputs first, as `Threads` dropped.
                        Err(_) => {
                            let exit = ExitReason::ThreadFailed("supervisor".into());
                            let mut stats = assemble_stats(
                                started.elapsed().as_secs_f64(),
                                None,
                                None,
                                &pipeline_shared,
                                &loop_shared,
                                &probe_names,
                            );
                            stats.stop = StopStats {
                                reason: exit.describe(),
                                outputs_zeroed: zeroed.load(Ordering::Relaxed),
                            };
                            stats.recording = recording_stats(&recording);
                            Ok(Outcome {
                                stats,
                                exit,
                                realtime: false,
                            })
                        }
                    }
                })
                .context("starting the supervisor thread")?
        };
        Ok(DaemonHandle {
            commands,
            supervisor,
            loop_shared,
            pipeline_shared,
            monitor_addr,
            recording,
        })
    }
}

async fn supervise(
    mut options: RunOptions,
    mut threads: Threads,
    mut commands: async_mpsc::UnboundedReceiver<Command>,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
    recording: Arc<RecordingStatus>,
) -> anyhow::Result<Outcome> {
    let started = Instant::now();
    let mut signals = Signals::new(options.handle_signals)?;
    let notifier = std::mem::replace(&mut options.notifier, Notifier::disabled());
    let mut health = Health::new(notifier, recording.clone());
    let _ = health.notifier.ready();
    tracing::info!("nanoforce running: all devices up");
    let mut interval = tokio::time::interval(Duration::from_millis(100));
    // A late look (after a slow reload) is not made up with a burst of looks.
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let deadline = options.duration.map(|d| started + d);
    let mut memory = MemoryWatch::default();
    let mut gate_log = GateLog::default();
    let mut next_memory_sample = started;
    let exit = loop {
        tokio::select! {
            _ = interval.tick() => {}
            signal = signals.next() => match signal {
                SignalEvent::Stop(name) => break ExitReason::Signal(name),
                SignalEvent::Reload => {
                    reload(&options, &mut threads, &mut health);
                    continue;
                }
            },
            command = commands.recv() => match command {
                Some(Command::Reload(gains)) => {
                    push_gains(&mut threads, *gains);
                    continue;
                }
                Some(Command::Stop) | None => break ExitReason::Requested,
            },
        }
        PanicInjection::check(options.inject.as_ref(), "supervisor");
        if let Some(failed) = dead_thread(&threads) {
            break ExitReason::ThreadFailed(failed);
        }
        if options.stop_when_frames_end && pipeline_shared.source_ended.load(Ordering::Relaxed) {
            break ExitReason::FramesEnded;
        }
        gate_log.poll(&loop_shared, Instant::now());
        health.check(
            &loop_shared,
            &pipeline_shared,
            &threads.events,
            options.status_line,
        );
        if Instant::now() >= next_memory_sample {
            memory.sample(started.elapsed().as_secs_f64());
            next_memory_sample += Duration::from_secs(1);
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break ExitReason::Duration;
        }
    };
    let _ = health.notifier.stopping();
    match &exit {
        ExitReason::ThreadFailed(name) => {
            tracing::error!("{name} thread ended unexpectedly: stopping with outputs at zero")
        }
        ExitReason::Signal(name) if !matches!(*name, "SIGINT" | "SIGTERM") => {
            tracing::warn!("{name}: stopping with outputs at zero")
        }
        _ => tracing::info!("stopping ({exit:?})"),
    }
    health.finish_status_line(options.status_line);
    let duration_s = started.elapsed().as_secs_f64();
    memory.sample(duration_s);
    let stream_shared = threads.stream.as_ref().map(|s| s.shared.clone());
    let (loop_report, tracker_report) = threads.shut_down(&exit.describe());
    let outputs_zeroed = threads.outputs_zeroed.load(Ordering::Relaxed);
    let realtime = loop_report.as_ref().is_some_and(|r| r.realtime);
    let mut stats = assemble_stats(
        duration_s,
        loop_report.as_ref(),
        tracker_report.as_ref(),
        &pipeline_shared,
        &loop_shared,
        &threads.probe_names,
    );
    stats.memory = memory.stats();
    stats.stop = StopStats {
        reason: exit.describe(),
        outputs_zeroed,
    };
    stats.recording = recording_stats(&recording);
    stats.stream = stream_shared.map(|s| s.stats());
    Ok(Outcome {
        stats,
        exit,
        realtime,
    })
}

fn push_gains(threads: &mut Threads, gains: TeleopGains) {
    if threads.gains.push(gains).is_err() {
        tracing::warn!("gain reload ignored: the haptic loop has not taken the previous one yet");
    }
}

fn reload(options: &RunOptions, threads: &mut Threads, health: &mut Health) {
    let _ = health.notifier.reloading();
    match options.reload.as_ref().map(|load| load()) {
        Some(Ok(reloaded)) => {
            if reloaded.needs_restart.is_empty() {
                tracing::info!(
                    "SIGHUP: teleoperation gains reloaded; re-centre the stylus to resume"
                );
                let _ = threads.events.send("gains reloaded (SIGHUP)".into());
            } else {
                let sections = reloaded
                    .needs_restart
                    .iter()
                    .map(|s| format!("[{s}]"))
                    .collect::<Vec<_>>()
                    .join(", ");
                tracing::warn!(
                    "SIGHUP: {sections} changed and need a restart to take effect \
                     (systemctl restart nanoforce); they keep their old values until then. \
                     [teleop] and [safety] reloaded; re-centre the stylus to resume"
                );
                let _ = threads.events.send(format!(
                    "gains reloaded (SIGHUP); {sections} changed, need a restart"
                ));
            }
            push_gains(threads, reloaded.gains);
        }
        Some(Err(e)) => {
            tracing::error!("SIGHUP: {e:#}; keeping the previous gains");
            let _ = threads.events.send(format!("reload rejected: {e:#}"));
        }
        None => tracing::warn!("SIGHUP: this run has no configuration file to reload"),
    }
    let _ = health.notifier.ready();
    health.resend_status();
}

impl SafetyState {
    /// Whether the teleoperation is in a fault state.
    pub fn is_fault(self) -> bool {
        matches!(self, SafetyState::HapticFault | SafetyState::DaqFault)
    }
}
