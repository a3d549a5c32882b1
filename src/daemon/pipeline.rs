//! The vision side of the daemon, two named threads joined by a latest-only slot:
//!
//! - `frames`: blocks on the [`FrameSource`] and drops each frame into a triple buffer.
//!   A frame the tracker has not taken yet is overwritten and counted as dropped, so a
//!   slow tracker never queues latency.
//! - `tracker`: takes the newest frame, runs the [`Estimator`] on it (every probe in
//!   view) and publishes each probe's estimate whole, stamped with its frame and probe
//!   ([`Published`]), into that probe's triple buffer, which the haptic loop reads, and
//!   the rings of the stream, the monitor and telemetry, then hands the frame to the
//!   session's frame recorder (a copy into a bounded queue, never a wait).
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use image::GrayImage;

use super::frame_record::FrameTap;
use super::snapshot::SnapshotTap;
use super::stats::{ForceErrors, Histogram};
use super::stream::EstimateTap;
use crate::control::Published;
use crate::hw::frames::{FrameError, FrameMeta, FrameSource, NO_TRUTH};
use crate::hw::Clock;
use crate::vision::Estimate;

/// Turns a frame into an estimate of each probe in view (the vision tracker, or a test
/// double).
pub trait Estimator: Send {
    /// How many probes it tracks (at least one).
    fn probes(&self) -> usize {
        1
    }

    /// Tracks every probe in `frame`: `estimates` holds one per probe, in order.
    fn estimate(&mut self, frame: &GrayImage, estimates: &mut [Estimate]);
}

/// A frame in the slot, with when it became available to the tracker.
#[derive(Debug, Clone)]
pub struct TimedFrame {
    pub image: GrayImage,
    pub meta: FrameMeta,
    pub available_s: f64,
}

impl Default for TimedFrame {
    fn default() -> Self {
        TimedFrame {
            image: GrayImage::new(0, 0),
            meta: FrameMeta {
                sequence: 0,
                captured_s: 0.0,
                truth: NO_TRUTH,
            },
            available_s: 0.0,
        }
    }
}

/// Counters the supervisor reads while the threads run.
#[derive(Debug, Default)]
pub struct PipelineShared {
    pub stop: AtomicBool,
    pub received: AtomicU64,
    /// Overwritten in the slot before the tracker took them.
    pub dropped: AtomicU64,
    /// Gaps in the source's own sequence numbers (dropped before they reached us).
    pub source_dropped: AtomicU64,
    pub source_errors: AtomicU64,
    pub tracked: AtomicU64,
    /// Frames in which the first probe was detected.
    pub detected: AtomicU64,
    /// The source said it has no more frames (a finite recording or a closed pipe).
    pub source_ended: AtomicBool,
    pub last_error: Mutex<Option<String>>,
}

impl PipelineShared {
    fn note_error(&self, message: String) {
        if let Ok(mut slot) = self.last_error.lock() {
            *slot = Some(message);
        }
    }
}

/// One telemetry row per tracked frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimateRecord {
    pub estimate: Published,
    pub processing_ms: f64,
    pub true_force_nn: Option<f64>,
}

/// What the tracker thread measured.
#[derive(Debug, Clone)]
pub struct TrackerReport {
    pub latency_ms: Histogram,
    /// Each probe's, in order.
    pub probes: Vec<ProbeReport>,
}

/// What the tracker measured of one probe.
#[derive(Debug, Clone, Default)]
pub struct ProbeReport {
    /// Frames in which it was detected.
    pub detected: u64,
    /// Only when frames carry ground truth (the simulated lab).
    pub force: Option<ForceErrors>,
}

/// Starts the `frames` thread. It wakes `tracker` whenever a frame lands.
pub fn spawn_frames(
    mut source: Box<dyn FrameSource>,
    mut slot: triple_buffer::Input<TimedFrame>,
    clock: Clock,
    shared: Arc<PipelineShared>,
    tracker: thread::Thread,
) -> std::io::Result<JoinHandle<()>> {
    thread::Builder::new().name("frames".into()).spawn(move || {
        let mut last_sequence: Option<u64> = None;
        while !shared.stop.load(Ordering::Relaxed) {
            let frame = slot.input_buffer_mut();
            match source.next_frame(&mut frame.image) {
                Ok(meta) => {
                    frame.meta = meta;
                    frame.available_s = clock.now_s();
                    if let Some(gap) = last_sequence.and_then(|s| meta.sequence.checked_sub(s + 1))
                    {
                        shared.source_dropped.fetch_add(gap, Ordering::Relaxed);
                    }
                    last_sequence = Some(meta.sequence);
                    shared.received.fetch_add(1, Ordering::Relaxed);
                    if slot.publish() {
                        shared.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    tracker.unpark();
                }
                Err(FrameError::EndOfStream { device }) => {
                    tracing::info!("{device}: no more frames");
                    shared.source_ended.store(true, Ordering::Relaxed);
                    break;
                }
                Err(e) => {
                    shared.source_errors.fetch_add(1, Ordering::Relaxed);
                    shared.note_error(e.to_string());
                    // A failing device must not spin the CPU; the source reopens itself.
                    thread::sleep(Duration::from_millis(100));
                }
            }
        }
    })
}

/// The tracker thread's ends of the slots.
pub struct TrackerSide {
    pub frames: triple_buffer::Output<TimedFrame>,
    /// One latest-only slot per probe, in order.
    pub estimates: Vec<triple_buffer::Input<Published>>,
    pub telemetry: rtrb::Producer<EstimateRecord>,
    /// Copies for the monitor and thumbnails (see [`super::snapshot`]), when wanted.
    pub snapshots: Option<SnapshotTap>,
    /// The live data stream's ring (see [`super::stream`]), when `[stream]` is on.
    pub stream: Option<EstimateTap>,
    /// Copies for the session's frames file (see [`super::frame_record`]), when recorded.
    pub recording: Option<FrameTap>,
}

/// Runs the tracker loop on the calling thread (spawned by the supervisor as `tracker`).
pub fn run_tracker(
    mut estimator: Box<dyn Estimator>,
    mut side: TrackerSide,
    clock: Clock,
    shared: Arc<PipelineShared>,
) -> TrackerReport {
    let mut latency_ms = Histogram::new(0.01, 1000.0);
    let count = estimator.probes();
    let mut probes = vec![ProbeReport::default(); count];
    let mut estimates = vec![Estimate::default(); count];
    let mut published = vec![Published::default(); count];
    let mut seq = 0u64;
    while !shared.stop.load(Ordering::Relaxed) {
        if !side.frames.update() {
            thread::park_timeout(Duration::from_millis(20));
            continue;
        }
        let frame = side.frames.output_buffer_mut();
        let started_s = clock.now_s();
        estimator.estimate(&frame.image, &mut estimates);
        let published_s = clock.now_s();
        // The capture time as the frame recording holds it, so a replay reproduces it.
        let frame_time_s = clock.to_whole_ns(frame.meta.captured_s);
        seq += 1;
        for (k, (slot, &estimate)) in published.iter_mut().zip(&estimates).enumerate() {
            *slot = Published {
                probe: k,
                seq,
                frame_sequence: frame.meta.sequence,
                frame_time_s,
                published_s,
                estimate,
            };
        }
        for (slot, p) in side.estimates.iter_mut().zip(&published) {
            slot.write(*p);
        }
        latency_ms.record((published_s - frame.available_s) * 1e3);
        shared.tracked.fetch_add(1, Ordering::Relaxed);
        if estimates[0].detected {
            shared.detected.fetch_add(1, Ordering::Relaxed);
        }
        if let Some(tap) = side.snapshots.as_mut() {
            tap.offer(published_s, &frame.image, &published);
        }
        if let Some(tap) = side.recording.as_mut() {
            tap.offer(&frame.image, &frame.meta);
        }
        for ((p, report), truth) in published.iter().zip(&mut probes).zip(frame.meta.truth) {
            if let Some(stream) = side.stream.as_mut() {
                stream.offer(p);
            }
            if p.estimate.detected {
                report.detected += 1;
            }
            let truth = truth.filter(|t| t.probe_in_view);
            let true_force_nn = truth.and_then(|t| t.force_nn);
            if let Some(true_nn) = true_force_nn {
                let errors = report.force.get_or_insert_with(ForceErrors::default);
                errors.record_truth(true_nn);
                if let Some(force_nn) = p.estimate.felt_force_nn() {
                    errors.record_error(force_nn, true_nn);
                }
            }
            let _ = side.telemetry.push(EstimateRecord {
                estimate: *p,
                processing_ms: (published_s - started_s) * 1e3,
                true_force_nn,
            });
        }
    }
    TrackerReport { latency_ms, probes }
}
