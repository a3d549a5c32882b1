//! The daemon's threads: starting them (the frame source, the tracker, the haptic loop,
//! the telemetry writer, the monitor and the stream), noticing one that ended on its
//! own, and stopping them in order, outputs first, each within a time limit.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::Context;

use super::{Devices, RunOptions};
use crate::control::Published;
use crate::control::TeleopGains;
use crate::daemon::frame_record::{FrameRecorder, FrameWriter, FRAMES_SHARE};
use crate::daemon::haptic_loop::{HapticLoop, LoopReport, LoopShared};
use crate::daemon::inject::{PanicInjection, PanickingEstimator, PanickingFrames, PanickingHaptic};
use crate::daemon::monitor::{self, DaemonView, MonitorHandle};
use crate::daemon::pipeline::{self, PipelineShared, TimedFrame, TrackerReport, TrackerSide};
use crate::daemon::recording::RecordingStatus;
use crate::daemon::snapshot::snapshot_channel;
use crate::daemon::stream::{self, StreamHandle, StreamShared};
use crate::daemon::telemetry::{self, Recorder};
use crate::hw::Clock;
use crate::session::utc::UtcAnchor;

/// Sizes of the rings between the loops and the telemetry writer (records, not bytes).
const TICK_RING: usize = 8192;
const ESTIMATE_RING: usize = 1024;

/// The running threads. Each handle is taken when the thread is stopped; dropping
/// `Threads` with the haptic loop still in it (the supervisor itself panicked) stops
/// everything the same way, outputs first.
pub(super) struct Threads {
    frames: Option<JoinHandle<()>>,
    tracker: Option<JoinHandle<TrackerReport>>,
    haptic: Option<JoinHandle<LoopReport>>,
    recorder: Option<(JoinHandle<std::io::Result<()>>, Arc<AtomicBool>)>,
    frame_recorder: Option<FrameRecorder>,
    pub(super) events: mpsc::Sender<String>,
    pub(super) gains: rtrb::Producer<TeleopGains>,
    pub(super) monitor: Option<MonitorHandle>,
    pub(super) stream: Option<StreamHandle>,
    loop_shared: Arc<LoopShared>,
    pipeline_shared: Arc<PipelineShared>,
    /// Set once the haptic loop has ended (its outputs zeroed, forces off).
    pub(super) outputs_zeroed: Arc<AtomicBool>,
    /// The probes' names, in order.
    pub(super) probe_names: Vec<String>,
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
    pub(super) fn shut_down(
        &mut self,
        reason: &str,
    ) -> (Option<LoopReport>, Option<TrackerReport>) {
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

/// Appends `line` to the file at `path`; a failure is logged, not raised (the stop
/// goes on).
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

/// Opens the session's recorders and starts every thread: the frame source, the
/// tracker, the haptic loop, the telemetry writer, the monitor and the stream.
pub(super) fn spawn_threads(
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

/// The name of a thread that ended on its own (only a panic ends them early; a frame
/// source that reached its end is not a failure).
pub(super) fn dead_thread(threads: &Threads) -> Option<String> {
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
