//! The supervisor: starts the loops, watches them, talks to systemd, handles signals,
//! and on the way out makes sure the outputs are at zero before it reports.
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc as async_mpsc;

use super::frame_record::{FrameRecorder, FrameWriter, FRAMES_SHARE};
use super::haptic_loop::{FeltProbe, GateLog, HapticLoop, LoopOptions, LoopReport, LoopShared};
use super::inject::{PanicInjection, PanickingEstimator, PanickingFrames, PanickingHaptic};
use super::monitor::{self, DaemonView, MonitorConfig, MonitorHandle};
use super::notify::Notifier;
use super::pipeline::{self, Estimator, PipelineShared, TimedFrame, TrackerReport, TrackerSide};
use super::recording::RecordingStatus;
use super::snapshot::snapshot_channel;
use super::stats::{
    ForceStats, FrameStats, LoopStats, MemoryStats, MemoryWatch, ProbeFrames, ProbeStats,
    RecordingStats, RunStats, SafetyStats, StopStats,
};
use super::stream::{self, StreamConfig, StreamHandle, StreamShared};
use super::supervisor_health::Health;
use super::telemetry::{self, Budget, Recorder};
use crate::config::PixelOrigin;
use crate::control::Published;
use crate::control::{SafetyState, TeleopGains};
use crate::hw::daq::RateOutput;
use crate::hw::frames::FrameSource;
use crate::hw::haptic::HapticDevice;
use crate::hw::Clock;
use crate::session::utc::UtcAnchor;
use crate::vision::SINGLE_NAME;

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

/// Sizes of the rings between the loops and the telemetry writer (records, not bytes).
const TICK_RING: usize = 8192;
const ESTIMATE_RING: usize = 1024;

/// The running threads. Each handle is taken when the thread is stopped; dropping
/// `Threads` with the haptic loop still in it (the supervisor itself panicked) stops
/// everything the same way, outputs first.
struct Threads {
    frames: Option<JoinHandle<()>>,
    tracker: Option<JoinHandle<TrackerReport>>,
    haptic: Option<JoinHandle<LoopReport>>,
    recorder: Option<(JoinHandle<std::io::Result<()>>, Arc<AtomicBool>)>,
    frame_recorder: Option<FrameRecorder>,
    events: mpsc::Sender<String>,
    gains: rtrb::Producer<TeleopGains>,
    monitor: Option<MonitorHandle>,
    stream: Option<StreamHandle>,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
    /// Set once the haptic loop has ended (its outputs zeroed, forces off).
    outputs_zeroed: Arc<AtomicBool>,
    /// The probes' names, in order.
    probe_names: Vec<String>,
    session_dir: Option<PathBuf>,
}

impl Drop for Threads {
    fn drop(&mut self) {
        if self.haptic.is_some() {
            let reason = if thread::panicking() {
                "panic in the supervisor thread"
            } else {
                "the supervisor ended early"
            };
            tracing::error!("{reason}: stopping with outputs at zero");
            self.shut_down(reason);
        }
    }
}

/// How long the stop waits for each loop to end.
const JOIN_LIMIT: Duration = Duration::from_secs(1);

/// Joins `handle` if its thread ends within `limit`; None when it did not (it is left
/// running: the process exit ends it). Err holds a panic's message.
fn join_within<T>(handle: JoinHandle<T>, limit: Duration) -> Option<Result<T, String>> {
    let deadline = Instant::now() + limit;
    while !handle.is_finished() && Instant::now() < deadline {
        thread::sleep(Duration::from_millis(2));
    }
    if !handle.is_finished() {
        return None;
    }
    Some(
        handle
            .join()
            .map_err(|payload| panic_message(payload.as_ref())),
    )
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "non-text panic".into())
}

impl Threads {
    /// Stops every thread: the haptic loop first (its outputs are zeroed as it ends or
    /// unwinds), then the stop goes into events.log, then the rest; the recorder last so
    /// it writes everything. Each wait is bounded.
    fn shut_down(&mut self, reason: &str) -> (Option<LoopReport>, Option<TrackerReport>) {
        self.loop_shared.stop.store(true, Ordering::Relaxed);
        let mut panics = Vec::new();
        let loop_report = match self.haptic.take().map(|h| join_within(h, JOIN_LIMIT)) {
            Some(Some(Ok(report))) => Some(report),
            Some(Some(Err(message))) => {
                panics.push(format!("haptic-loop: {message}"));
                None
            }
            _ => None,
        };
        let zeroed = loop_ended(&loop_report, &panics);
        self.outputs_zeroed.store(zeroed, Ordering::Relaxed);
        self.pipeline_shared.stop.store(true, Ordering::Relaxed);
        let tracker_report = match self.tracker.take().map(|t| {
            t.thread().unpark();
            join_within(t, JOIN_LIMIT)
        }) {
            Some(Some(Ok(report))) => Some(report),
            Some(Some(Err(message))) => {
                panics.push(format!("tracker: {message}"));
                None
            }
            _ => None,
        };
        let outputs = if zeroed {
            "outputs at zero, forces off"
        } else {
            tracing::error!(
                "the haptic loop did not end within {JOIN_LIMIT:?}: outputs not confirmed at zero"
            );
            "the haptic loop did not end: outputs NOT confirmed at zero"
        };
        let detail = if panics.is_empty() {
            String::new()
        } else {
            format!(" ({})", panics.join("; "))
        };
        let stop_line = format!("stop: {reason}{detail}; {outputs}");
        let recorder_alive = self
            .recorder
            .as_ref()
            .is_some_and(|(h, _)| !h.is_finished());
        if recorder_alive {
            let _ = self.events.send(stop_line);
        } else if let Some(dir) = &self.session_dir {
            // The writer thread is gone (it panicked): the stop goes in directly.
            append_line(&dir.join("events.log"), &stop_line);
        }
        if let Some(monitor) = self.monitor.take() {
            monitor.stop();
        }
        // The loops have ended: the stream sends what they queued, then ends.
        if let Some(handle) = self.stream.take().and_then(StreamHandle::stop) {
            match join_within(handle, JOIN_LIMIT) {
                Some(Ok(())) => {}
                Some(Err(message)) => tracing::error!("stream thread panicked: {message}"),
                None => tracing::warn!("the stream thread did not end; not waiting for it"),
            }
        }
        // A frame source may be blocked in a read (a pipe): give it a moment, then leave it.
        if let Some(frames) = self.frames.take() {
            if join_within(frames, JOIN_LIMIT).is_none() {
                tracing::warn!("frame source still blocked in a read; not waiting for it");
            }
        }
        if let Some(frame_recorder) = self.frame_recorder.take() {
            frame_recorder.finish(JOIN_LIMIT * 2);
        }
        if let Some((handle, stop)) = self.recorder.take() {
            stop.store(true, Ordering::Relaxed);
            match join_within(handle, JOIN_LIMIT * 2) {
                Some(Ok(Ok(()))) => {}
                Some(Ok(Err(e))) => tracing::error!("telemetry recording failed: {e}"),
                Some(Err(message)) => tracing::error!("telemetry thread panicked: {message}"),
                None => tracing::error!("the telemetry thread did not end; files may be short"),
            }
        }
        (loop_report, tracker_report)
    }
}

fn append_line(path: &std::path::Path, line: &str) {
    use std::io::Write;
    let appended = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .and_then(|mut f| writeln!(f, "{line}"));
    if let Err(e) = appended {
        tracing::error!("writing {}: {e}", path.display());
    }
}

/// The haptic loop's thread ended (normally or by a panic): either way its outputs were
/// zeroed by `Outputs`' drop.
fn loop_ended(report: &Option<LoopReport>, panics: &[String]) -> bool {
    report.is_some() || panics.iter().any(|p| p.starts_with("haptic-loop"))
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

fn spawn_threads(
    gains: TeleopGains,
    devices: Devices,
    options: &RunOptions,
    clock: Clock,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
    recording: Arc<RecordingStatus>,
) -> anyhow::Result<Threads> {
    let devices = inject_panics(devices, options.inject.as_ref());
    let probe_names = devices.names.clone();
    let (frames_in, frames_out) = triple_buffer::triple_buffer(&TimedFrame::default());
    let (estimates_in, estimates_out): (Vec<_>, Vec<_>) = devices
        .stages
        .iter()
        .map(|_| triple_buffer::triple_buffer(&Published::default()))
        .unzip();
    let (ticks_tx, ticks_rx) = rtrb::RingBuffer::new(TICK_RING);
    let (est_tx, est_rx) = rtrb::RingBuffer::new(ESTIMATE_RING);
    let (gains_tx, gains_rx) = rtrb::RingBuffer::new(4);
    let (events_tx, events_rx) = mpsc::channel();
    // The stream and the monitor first: they only read, and a socket refused or a port
    // in use stops the start right here (a stream not yet joined stops as it drops).
    // t = 0 in UTC, one anchor for the session's CSVs and the stream.
    let anchor = UtcAnchor::measure(&clock);
    let (stream, estimate_tap, haptic_tap) = match options.stream.udp {
        Some(addr) => {
            let shared = Arc::new(StreamShared::default());
            let started = stream::start(&options.stream, shared, anchor, options.pixel_origin)
                .with_context(|| format!("starting the data stream to {addr} ([stream] udp)"))?;
            (
                Some(started.handle),
                Some(started.estimates),
                started.haptic,
            )
        }
        None => (None, None, None),
    };
    let (snapshots, monitor) = match &options.monitor {
        Some(config) if config.wants_snapshots(options.session_dir.is_some()) => {
            let (tap, reader) = snapshot_channel(config.frame_hz);
            let view = DaemonView {
                loop_shared: loop_shared.clone(),
                pipeline_shared: pipeline_shared.clone(),
                recording: recording.clone(),
                stream: stream.as_ref().map(|s| s.shared.clone()),
                inject: options.inject.clone(),
                probe_names: devices.names.clone(),
            };
            let handle = monitor::start(config, reader, view, options.session_dir.clone())
                .context("starting the monitor")?;
            (Some(tap), Some(handle))
        }
        _ => (None, None),
    };

    let (frame_tap, frame_recorder) = match &options.session_dir {
        Some(dir) => {
            let writer = FrameWriter {
                dir: dir.clone(),
                max_bytes: options
                    .recordings_budget
                    .as_ref()
                    .map(|b| (b.max_bytes as f64 * FRAMES_SHARE) as u64),
                events: events_tx.clone(),
            };
            let (tap, recorder) = FrameRecorder::start(writer, clock, recording.clone())
                .context("starting the frame-recorder thread")?;
            (Some(tap), Some(recorder))
        }
        None => (None, None),
    };
    let recorder = match &options.session_dir {
        Some(dir) => {
            let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
            let recorder = Recorder {
                dir: dir.clone(),
                anchor,
                records_frames: frame_recorder.is_some(),
                config_file: options.config_file.clone(),
                pixel_origin: options.pixel_origin,
                probe_names: probe_names.clone(),
                ticks: ticks_rx,
                estimates: est_rx,
                events: events_rx,
                status: recording,
                budget: options.recordings_budget.clone(),
                inject: options.inject.clone(),
            };
            let handle = telemetry::spawn_recorder(recorder, stop.clone())
                .context("starting the telemetry thread")?;
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
            stream: estimate_tap,
            recording: frame_tap,
        };
        let estimator = devices.estimator;
        thread::Builder::new()
            .name("tracker".into())
            .spawn(move || pipeline::run_tracker(estimator, side, clock, shared))
            .context("starting the tracker thread")?
    };
    let pipeline_for_threads = pipeline_shared.clone();
    let frames = pipeline::spawn_frames(
        devices.frames,
        frames_in,
        clock,
        pipeline_shared,
        tracker.thread().clone(),
    )
    .context("starting the frames thread")?;
    let outputs_zeroed = Arc::new(AtomicBool::new(false));
    let shared_for_threads = loop_shared.clone();
    let mut haptic_loop = HapticLoop::new(
        gains,
        devices.felt,
        devices.haptic,
        devices.stages,
        clock,
        estimates_out,
        gains_rx,
        ticks_tx,
        loop_shared,
        options.loop_options.clone(),
    );
    haptic_loop.stream = haptic_tap;
    let haptic = haptic_loop
        .spawn()
        .context("starting the haptic loop thread")?;
    Ok(Threads {
        frames: Some(frames),
        tracker: Some(tracker),
        haptic: Some(haptic),
        recorder,
        frame_recorder,
        events: events_tx,
        gains: gains_tx,
        monitor,
        stream,
        loop_shared: shared_for_threads,
        pipeline_shared: pipeline_for_threads,
        outputs_zeroed,
        session_dir: options.session_dir.clone(),
        probe_names,
    })
}

/// The devices with a test's panic injection wrapped around the one it names.
fn inject_panics(devices: Devices, inject: Option<&PanicInjection>) -> Devices {
    let Some(injection) = inject.cloned() else {
        return devices;
    };
    let Devices {
        mut frames,
        mut estimator,
        stages,
        mut haptic,
        names,
        felt,
    } = devices;
    match injection.thread {
        "frames" => {
            frames = Box::new(PanickingFrames {
                inner: frames,
                injection,
            })
        }
        "tracker" => {
            estimator = Box::new(PanickingEstimator {
                inner: estimator,
                injection,
            })
        }
        "haptic-loop" => {
            haptic = Box::new(PanickingHaptic {
                inner: haptic,
                injection,
            })
        }
        _ => {}
    }
    Devices {
        frames,
        estimator,
        stages,
        haptic,
        names,
        felt,
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

fn recording_stats(recording: &RecordingStatus) -> RecordingStats {
    let frames = &recording.frames;
    RecordingStats {
        state: recording.state().as_str().into(),
        error: recording.error(),
        frames_recorded: frames.recorded.load(Ordering::Relaxed),
        frames_dropped: frames.dropped.load(Ordering::Relaxed),
        frames_mb: frames.bytes.load(Ordering::Relaxed) as f64 / 1e6,
        frames_stopped: frames.stopped.load(Ordering::Relaxed),
    }
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

/// The name of a thread that ended on its own (only a panic ends them early; a frame
/// source that reached its end is not a failure).
fn dead_thread(threads: &Threads) -> Option<String> {
    let ended = |h: Option<bool>| h.unwrap_or(false);
    if ended(threads.haptic.as_ref().map(JoinHandle::is_finished)) {
        return Some("haptic-loop".into());
    }
    if ended(threads.tracker.as_ref().map(JoinHandle::is_finished)) {
        return Some("tracker".into());
    }
    if ended(threads.frames.as_ref().map(JoinHandle::is_finished))
        && !threads.pipeline_shared.source_ended.load(Ordering::Relaxed)
    {
        return Some("frames".into());
    }
    if ended(threads.recorder.as_ref().map(|(h, _)| h.is_finished())) {
        return Some("telemetry".into());
    }
    if ended(
        threads
            .frame_recorder
            .as_ref()
            .map(FrameRecorder::is_finished),
    ) {
        return Some("frame-recorder".into());
    }
    if threads
        .monitor
        .as_ref()
        .is_some_and(MonitorHandle::is_finished)
    {
        return Some("monitor".into());
    }
    if threads
        .stream
        .as_ref()
        .is_some_and(StreamHandle::is_finished)
    {
        return Some("stream".into());
    }
    None
}

/// `names`: the probes', in order.
fn assemble_stats(
    duration_s: f64,
    loop_report: Option<&LoopReport>,
    tracker: Option<&TrackerReport>,
    pipeline: &PipelineShared,
    loop_shared: &LoopShared,
    names: &[String],
) -> RunStats {
    let probe = |k: usize| tracker.and_then(|t| t.probes.get(k));
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
        force: ForceStats::from_errors(probe(0).and_then(|p| p.force.as_ref())),
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
        stop: StopStats::default(),
        recording: RecordingStats::default(),
        stream: None,
        probes: names
            .iter()
            .enumerate()
            .map(|(k, name)| ProbeStats {
                name: name.clone(),
                frames: ProbeFrames {
                    detected: probe(k).map_or(0, |p| p.detected),
                },
                force: ForceStats::from_errors(probe(k).and_then(|p| p.force.as_ref())),
            })
            .collect(),
    }
}

/// The signals the daemon reacts to.
enum SignalEvent {
    Stop(&'static str),
    Reload,
}

struct Signals {
    /// SIGHUP, then each of [`STOP_SIGNALS`].
    streams: Vec<tokio::signal::unix::Signal>,
}

impl Signals {
    /// tokio's handlers only note the signal and wake the supervisor (async-signal-safe);
    /// everything else happens here, on the supervisor's thread.
    fn new(enabled: bool) -> anyhow::Result<Self> {
        use tokio::signal::unix::{signal, SignalKind};
        if !enabled {
            return Ok(Signals {
                streams: Vec::new(),
            });
        }
        let mut streams =
            vec![signal(SignalKind::hangup()).context("installing the SIGHUP handler")?];
        for (number, name) in STOP_SIGNALS {
            streams.push(
                signal(SignalKind::from_raw(number))
                    .with_context(|| format!("installing the {name} handler"))?,
            );
        }
        Ok(Signals { streams })
    }

    async fn next(&mut self) -> SignalEvent {
        if self.streams.is_empty() {
            return std::future::pending().await;
        }
        let streams = &mut self.streams;
        let index = std::future::poll_fn(|cx| {
            for (i, stream) in streams.iter_mut().enumerate() {
                if stream.poll_recv(cx).is_ready() {
                    return std::task::Poll::Ready(i);
                }
            }
            std::task::Poll::Pending
        })
        .await;
        match index {
            0 => SignalEvent::Reload,
            i => SignalEvent::Stop(STOP_SIGNALS[i - 1].1),
        }
    }
}

impl SafetyState {
    /// Whether the teleoperation is in a fault state.
    pub fn is_fault(self) -> bool {
        matches!(self, SafetyState::HapticFault | SafetyState::DaqFault)
    }
}
