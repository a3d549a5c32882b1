//! The run's statistics as the stats JSON reports them, assembled from what the loops
//! and the recorder counted.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::daemon::haptic_loop::{LoopReport, LoopShared};
use crate::daemon::pipeline::{PipelineShared, TrackerReport};
use crate::daemon::recording::RecordingStatus;
use crate::daemon::stats::{
    ForceStats, FrameStats, LoopStats, MemoryStats, ProbeFrames, ProbeStats, RecordingStats,
    RunStats, SafetyStats, StopStats,
};

/// What the session recorder wrote and dropped.
pub(super) fn recording_stats(recording: &RecordingStatus) -> RecordingStats {
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

/// The run's statistics over `duration_s` seconds; `names`: the probes', in order.
pub(super) fn assemble_stats(
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
    // A count from the loop's report when it ended, else its live counter.
    let counted = |live: &AtomicU64, reported: fn(&LoopReport) -> u64| {
        loop_report.map_or_else(|| live.load(Ordering::Relaxed), reported)
    };
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
            stale_events: counted(&loop_shared.stale_events, |r| r.counters.stale_events),
            faults: counted(&loop_shared.faults, |r| r.counters.faults),
            gate_held: counted(&loop_shared.gate_held, |r| r.gate.held),
            gate_attenuated: counted(&loop_shared.gate_attenuated, |r| r.gate.attenuated),
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
