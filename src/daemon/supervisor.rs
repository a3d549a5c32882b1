//! The supervisor: starts the loops, watches them, talks to systemd, handles signals,
//! and on the way out makes sure the outputs are at zero before it reports.
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc as async_mpsc;

use super::haptic_loop::{GateLog, HapticLoop, LoopOptions, LoopReport, LoopShared};
use super::notify::Notifier;
use super::pipeline::{self, Estimator, PipelineShared, TimedFrame, TrackerReport, TrackerSide};
use super::snapshot::snapshot_channel;
use super::stats::{
    ForceStats, FrameStats, LoopStats, MemoryStats, MemoryWatch, RunStats, SafetyStats,
};
use super::supervisor_health::Health;
use super::telemetry::{self, Recorder};
use super::PublishedEstimate;
use crate::config::PixelOrigin;
use crate::control::{SafetyState, TeleopGains};
use crate::hw::daq::RateOutput;
use crate::hw::frames::FrameSource;
use crate::hw::haptic::HapticDevice;
use crate::hw::Clock;
use crate::monitor::{self, DaemonView, MonitorConfig, MonitorHandle};

/// The opened devices and the tracker, ready to run.
pub struct Devices {
    pub frames: Box<dyn FrameSource>,
    pub estimator: Box<dyn Estimator>,
    pub stage: Box<dyn RateOutput>,
    pub haptic: Box<dyn HapticDevice>,
}

/// How to run.
pub struct RunOptions {
    /// Stop after this long (None: until a signal or a stop request).
    pub duration: Option<Duration>,
    /// Record telemetry into this session folder.
    pub session_dir: Option<PathBuf>,
    /// Print a live status line on standard error.
    pub status_line: bool,
    /// Handle SIGINT/SIGTERM (stop) and SIGHUP (reload gains through `reload`).
    pub handle_signals: bool,
    /// Reads and validates new gains for SIGHUP; an error keeps the old gains.
    pub reload: Option<Box<dyn Fn() -> anyhow::Result<TeleopGains> + Send>>,
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
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: None,
            session_dir: None,
            status_line: false,
            handle_signals: false,
            reload: None,
            loop_options: LoopOptions::default(),
            notifier: Notifier::disabled(),
            stop_when_frames_end: false,
            clock: Clock::start(),
            monitor: None,
            pixel_origin: PixelOrigin::Centre,
        }
    }
}

/// Why the run ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ExitReason {
    Duration,
    Signal(&'static str),
    Requested,
    FramesEnded,
    /// A loop thread died (panicked): the outputs were zeroed, the run is a failure.
    ThreadFailed(String),
}

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

/// Sizes of the rings between the loops and the telemetry writer (records, not bytes).
const TICK_RING: usize = 8192;
const ESTIMATE_RING: usize = 1024;

struct Threads {
    frames: JoinHandle<()>,
    tracker: JoinHandle<TrackerReport>,
    haptic: JoinHandle<LoopReport>,
    recorder: Option<(
        JoinHandle<std::io::Result<()>>,
        Arc<std::sync::atomic::AtomicBool>,
    )>,
    events: mpsc::Sender<String>,
    gains: rtrb::Producer<TeleopGains>,
    monitor: Option<MonitorHandle>,
}

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
        let mut threads = spawn_threads(
            gains,
            devices,
            &options,
            clock,
            loop_shared.clone(),
            pipeline_shared.clone(),
        )?;
        let monitor_addr = threads.monitor.as_mut().and_then(|m| m.local_addr);
        let supervisor = {
            let loop_shared = loop_shared.clone();
            let pipeline_shared = pipeline_shared.clone();
            thread::Builder::new()
                .name("supervisor".into())
                .spawn(move || {
                    let runtime = tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                        .context("starting the supervisor's runtime")?;
                    runtime.block_on(supervise(
                        options,
                        threads,
                        commands_rx,
                        loop_shared,
                        pipeline_shared,
                    ))
                })
                .context("starting the supervisor thread")?
        };
        Ok(DaemonHandle {
            commands,
            supervisor,
            loop_shared,
            pipeline_shared,
            monitor_addr,
        })
    }
}

fn spawn_threads(
    gains: TeleopGains,
    devices: Devices,
    options: &RunOptions,
    clock: Clock,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
) -> anyhow::Result<Threads> {
    let (frames_in, frames_out) = triple_buffer::triple_buffer(&TimedFrame::default());
    let (estimates_in, estimates_out) = triple_buffer::triple_buffer(&PublishedEstimate::default());
    let (ticks_tx, ticks_rx) = rtrb::RingBuffer::new(TICK_RING);
    let (est_tx, est_rx) = rtrb::RingBuffer::new(ESTIMATE_RING);
    let (gains_tx, gains_rx) = rtrb::RingBuffer::new(4);
    let (events_tx, events_rx) = mpsc::channel();
    // The monitor first: it only reads, and a port in use stops the start right here.
    let (snapshots, monitor) = match &options.monitor {
        Some(config) if config.wants_snapshots(options.session_dir.is_some()) => {
            let (tap, reader) = snapshot_channel(config.frame_hz);
            let view = DaemonView {
                loop_shared: loop_shared.clone(),
                pipeline_shared: pipeline_shared.clone(),
            };
            let handle = monitor::start(config, reader, view, options.session_dir.clone())
                .context("starting the monitor")?;
            (Some(tap), Some(handle))
        }
        _ => (None, None),
    };

    let recorder = match &options.session_dir {
        Some(dir) => {
            let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
            let recorder = Recorder {
                dir: dir.clone(),
                pixel_origin: options.pixel_origin,
                ticks: ticks_rx,
                estimates: est_rx,
                events: events_rx,
            };
            let handle = telemetry::spawn_recorder(recorder, stop.clone())
                .with_context(|| format!("recording into {}", dir.display()))?;
            Some((handle, stop))
        }
        None => None,
    };

    let tracker = {
        let shared = pipeline_shared.clone();
        let side = TrackerSide {
            frames: frames_out,
            estimates: estimates_in,
            telemetry: est_tx,
            snapshots,
        };
        let estimator = devices.estimator;
        thread::Builder::new()
            .name("tracker".into())
            .spawn(move || pipeline::run_tracker(estimator, side, clock, shared))
            .context("starting the tracker thread")?
    };
    let frames = pipeline::spawn_frames(
        devices.frames,
        frames_in,
        clock,
        pipeline_shared,
        tracker.thread().clone(),
    )
    .context("starting the frames thread")?;
    let haptic = HapticLoop::new(
        gains,
        devices.haptic,
        devices.stage,
        clock,
        estimates_out,
        gains_rx,
        ticks_tx,
        loop_shared,
        options.loop_options.clone(),
    )
    .spawn()
    .context("starting the haptic loop thread")?;
    Ok(Threads {
        frames,
        tracker,
        haptic,
        recorder,
        events: events_tx,
        gains: gains_tx,
        monitor,
    })
}

async fn supervise(
    mut options: RunOptions,
    mut threads: Threads,
    mut commands: async_mpsc::UnboundedReceiver<Command>,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
) -> anyhow::Result<Outcome> {
    let started = Instant::now();
    let mut signals = Signals::new(options.handle_signals)?;
    let notifier = std::mem::replace(&mut options.notifier, Notifier::disabled());
    let mut health = Health::new(notifier);
    let _ = health.notifier.ready();
    tracing::info!("nanoforce running: all devices up");
    let mut interval = tokio::time::interval(Duration::from_millis(100));
    let deadline = options.duration.map(|d| started + d);
    let mut memory = MemoryWatch::default();
    let mut gate_log = GateLog::default();
    let mut next_memory_sample = started;
    let exit = loop {
        tokio::select! {
            _ = interval.tick() => {}
            signal = signals.next() => match signal {
                SignalEvent::Stop(name) => break ExitReason::Signal(name),
                SignalEvent::Reload => reload(&options, &mut threads, &mut health),
            },
            command = commands.recv() => match command {
                Some(Command::Reload(gains)) => push_gains(&mut threads, *gains),
                Some(Command::Stop) | None => break ExitReason::Requested,
            },
        }
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
    if let ExitReason::ThreadFailed(name) = &exit {
        tracing::error!("{name} thread ended unexpectedly: stopping with outputs at zero");
    } else {
        tracing::info!("stopping ({exit:?})");
    }
    health.finish_status_line(options.status_line);
    let duration_s = started.elapsed().as_secs_f64();
    memory.sample(duration_s);
    let (loop_report, tracker_report) = stop_threads(threads, &loop_shared, &pipeline_shared);
    let realtime = loop_report.as_ref().is_some_and(|r| r.realtime);
    let mut stats = assemble_stats(
        duration_s,
        loop_report.as_ref(),
        tracker_report.as_ref(),
        &pipeline_shared,
        &loop_shared,
    );
    stats.memory = memory.stats();
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
        Some(Ok(gains)) => {
            tracing::info!("SIGHUP: teleoperation gains reloaded; re-centre the stylus to resume");
            let _ = threads.events.send("gains reloaded (SIGHUP)".into());
            push_gains(threads, gains);
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

/// The name of a loop thread that ended on its own (only a panic ends them early).
fn dead_thread(threads: &Threads) -> Option<String> {
    if threads.haptic.is_finished() {
        return Some("haptic-loop".into());
    }
    if threads.tracker.is_finished() {
        return Some("tracker".into());
    }
    None
}

fn stop_threads(
    threads: Threads,
    loop_shared: &LoopShared,
    pipeline_shared: &PipelineShared,
) -> (Option<LoopReport>, Option<TrackerReport>) {
    // The haptic loop first: its outputs are zeroed as it ends (or as it unwinds).
    loop_shared.stop.store(true, Ordering::Relaxed);
    let loop_report = threads.haptic.join().ok();
    pipeline_shared.stop.store(true, Ordering::Relaxed);
    threads.tracker.thread().unpark();
    let tracker_report = threads.tracker.join().ok();
    if let Some(monitor) = threads.monitor {
        monitor.stop();
    }
    // A frame source may be blocked in a read (a pipe): give it a moment, then leave it.
    let deadline = Instant::now() + Duration::from_secs(1);
    while !threads.frames.is_finished() && Instant::now() < deadline {
        thread::sleep(Duration::from_millis(10));
    }
    if threads.frames.is_finished() {
        let _ = threads.frames.join();
    } else {
        tracing::warn!("frame source still blocked in a read; not waiting for it");
    }
    if let Some((handle, stop)) = threads.recorder {
        stop.store(true, Ordering::Relaxed);
        match handle.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => tracing::error!("telemetry recording failed: {e}"),
            Err(_) => tracing::error!("telemetry thread panicked"),
        }
    }
    (loop_report, tracker_report)
}

fn assemble_stats(
    duration_s: f64,
    loop_report: Option<&LoopReport>,
    tracker: Option<&TrackerReport>,
    pipeline: &PipelineShared,
    loop_shared: &LoopShared,
) -> RunStats {
    let ticks = loop_report.map_or(0, |r| r.ticks);
    let periods = loop_report.map(|r| &r.periods_us);
    let latency = tracker.map(|t| &t.latency_ms);
    RunStats {
        duration_s,
        haptic_loop: LoopStats {
            ticks,
            rate_hz: ticks as f64 / duration_s.max(1e-9),
            period_us_p50: periods.and_then(|h| h.quantile(0.5)),
            period_us_p99: periods.and_then(|h| h.quantile(0.99)),
            period_us_max: periods.filter(|h| h.count() > 0).map(|h| h.max()),
            overruns: loop_report.map_or(0, |r| r.overruns),
        },
        frames: FrameStats {
            received: pipeline.received.load(Ordering::Relaxed),
            tracked: pipeline.tracked.load(Ordering::Relaxed),
            detected: pipeline.detected.load(Ordering::Relaxed),
            dropped: pipeline.dropped.load(Ordering::Relaxed)
                + pipeline.source_dropped.load(Ordering::Relaxed),
            latency_ms_p50: latency.and_then(|h| h.quantile(0.5)),
            latency_ms_p99: latency.and_then(|h| h.quantile(0.99)),
        },
        force: ForceStats::from_errors(tracker.and_then(|t| t.force.as_ref())),
        safety: SafetyStats {
            stale_events: loop_report.map_or_else(
                || loop_shared.stale_events.load(Ordering::Relaxed),
                |r| r.counters.stale_events,
            ),
            faults: loop_report.map_or_else(
                || loop_shared.faults.load(Ordering::Relaxed),
                |r| r.counters.faults,
            ),
            gate_held: loop_report.map_or_else(
                || loop_shared.gate_held.load(Ordering::Relaxed),
                |r| r.gate.held,
            ),
            gate_attenuated: loop_report.map_or_else(
                || loop_shared.gate_attenuated.load(Ordering::Relaxed),
                |r| r.gate.attenuated,
            ),
        },
        memory: MemoryStats::default(),
    }
}

/// The signals the daemon reacts to.
enum SignalEvent {
    Stop(&'static str),
    Reload,
}

struct Signals {
    streams: Option<[tokio::signal::unix::Signal; 3]>,
}

impl Signals {
    fn new(enabled: bool) -> anyhow::Result<Self> {
        use tokio::signal::unix::{signal, SignalKind};
        if !enabled {
            return Ok(Signals { streams: None });
        }
        Ok(Signals {
            streams: Some([
                signal(SignalKind::interrupt()).context("installing the SIGINT handler")?,
                signal(SignalKind::terminate()).context("installing the SIGTERM handler")?,
                signal(SignalKind::hangup()).context("installing the SIGHUP handler")?,
            ]),
        })
    }

    async fn next(&mut self) -> SignalEvent {
        match &mut self.streams {
            None => std::future::pending().await,
            Some([int, term, hup]) => tokio::select! {
                _ = int.recv() => SignalEvent::Stop("SIGINT"),
                _ = term.recv() => SignalEvent::Stop("SIGTERM"),
                _ = hup.recv() => SignalEvent::Reload,
            },
        }
    }
}

impl SafetyState {
    /// Whether the teleoperation is in a fault state.
    pub fn is_fault(self) -> bool {
        matches!(self, SafetyState::HapticFault | SafetyState::DaqFault)
    }
}
