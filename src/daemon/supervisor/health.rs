//! The supervisor's view of the loops: are they alive and progressing (the systemd
//! watchdog is fed only while they are), what changed since the last look (logged
//! once, not every tick), and the status for `systemctl status` and the terminal.
use std::io::{IsTerminal, Write};
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use crate::control::SafetyState;
use crate::daemon::haptic_loop::LoopShared;
use crate::daemon::notify::Notifier;
use crate::daemon::pipeline::PipelineShared;
use crate::daemon::recording::{RecordingState, RecordingStatus};

/// A frame source silent for longer than this makes the pipeline unhealthy.
const FRAME_SILENCE: Duration = Duration::from_secs(2);
/// The haptic loop stalled: its tick count has not moved for this long. Judged on time,
/// not between two looks, so looks that come close together (a burst of SIGHUPs) do not
/// see a 1 kHz loop "stop"; several times the supervisor's 100 ms look.
const HAPTIC_SILENCE: Duration = Duration::from_millis(300);
/// Before its first tick the loop is still preparing (real-time priority, locking its
/// memory): not judged until it has run, or until this long after READY.
const LOOP_START_GRACE: Duration = Duration::from_secs(2);

pub(super) struct Health {
    pub notifier: Notifier,
    last_watchdog: Instant,
    started: Instant,
    last_ticks: u64,
    last_tick_at: Instant,
    last_frame_at: Instant,
    last_received: u64,
    healthy: bool,
    state: SafetyState,
    rates: Rates,
    last_status: Instant,
    status_text: String,
    terminal: bool,
    recording: Arc<RecordingStatus>,
    recording_state: RecordingState,
}

/// Counts at the last status, to turn into rates.
#[derive(Clone, Copy)]
struct Rates {
    at: Instant,
    ticks: u64,
    received: u64,
    tracked: u64,
    detected: u64,
}

impl Health {
    pub fn new(notifier: Notifier, recording: Arc<RecordingStatus>) -> Self {
        let now = Instant::now();
        let recording_state = recording.state();
        Health {
            notifier,
            last_watchdog: now,
            started: now,
            last_ticks: 0,
            last_tick_at: now,
            last_frame_at: now,
            last_received: 0,
            healthy: true,
            state: SafetyState::WaitingForCentre,
            rates: Rates {
                at: now,
                ticks: 0,
                received: 0,
                tracked: 0,
                detected: 0,
            },
            last_status: now,
            status_text: String::new(),
            terminal: std::io::stderr().is_terminal(),
            recording,
            recording_state,
        }
    }

    /// One look, every 100 ms.
    pub fn check(
        &mut self,
        loop_shared: &LoopShared,
        pipeline: &PipelineShared,
        events: &mpsc::Sender<String>,
        status_line: bool,
    ) {
        let now = Instant::now();
        let ticks = loop_shared.ticks.load(Ordering::Relaxed);
        let received = pipeline.received.load(Ordering::Relaxed);
        let tracked = pipeline.tracked.load(Ordering::Relaxed);
        if received != self.last_received {
            self.last_received = received;
            self.last_frame_at = now;
        }
        if ticks != self.last_ticks {
            self.last_ticks = ticks;
            self.last_tick_at = now;
        }
        let haptic_alive = haptic_alive(ticks, now - self.started, now - self.last_tick_at);
        let frames_alive = now - self.last_frame_at < FRAME_SILENCE
            || pipeline.source_ended.load(Ordering::Relaxed);
        let tracker_alive = received.saturating_sub(tracked) <= 2
            || pipeline.tracked.load(Ordering::Relaxed) > self.rates.tracked;
        let healthy = haptic_alive && frames_alive && tracker_alive;
        if healthy != self.healthy {
            if healthy {
                tracing::info!("all loops healthy again");
            } else {
                tracing::warn!(
                    "unhealthy: haptic loop {}, frames {}, tracker {}; watchdog pings paused",
                    alive(haptic_alive),
                    alive(frames_alive),
                    alive(tracker_alive)
                );
            }
            self.healthy = healthy;
        }
        self.feed_watchdog(now);
        self.log_changes(loop_shared, pipeline, events);
        let recording_state = self.recording.state();
        let recording_changed = recording_state != self.recording_state;
        if recording_changed {
            self.recording_state = recording_state;
            // The line reaches events.log only if the disk takes it.
            let _ = events.send(self.recording.describe());
        }
        if recording_changed || now - self.last_status >= Duration::from_secs(1) {
            self.update_status(now, loop_shared, pipeline);
        }
        if status_line && self.terminal {
            eprint!("\r{:<110}", self.status_text);
            let _ = std::io::stderr().flush();
        }
    }

    fn feed_watchdog(&mut self, now: Instant) {
        if let Some(interval) = self.notifier.watchdog_interval() {
            if self.healthy && now - self.last_watchdog >= interval / 2 {
                let _ = self.notifier.watchdog();
                self.last_watchdog = now;
            }
        }
    }

    fn log_changes(
        &mut self,
        loop_shared: &LoopShared,
        pipeline: &PipelineShared,
        events: &mpsc::Sender<String>,
    ) {
        let fault = loop_shared
            .last_fault
            .lock()
            .ok()
            .and_then(|mut f| f.take());
        if let Some(message) = fault {
            tracing::error!("{message}");
            let _ = events.send(format!("fault: {message}"));
        }
        let source_error = pipeline.last_error.lock().ok().and_then(|mut e| e.take());
        if let Some(message) = source_error {
            tracing::warn!("frame source: {message}");
            let _ = events.send(format!("frame source: {message}"));
        }
        let state = loop_shared.state();
        if state != self.state {
            let line = format!("state {} -> {}", self.state.as_str(), state.as_str());
            if state.is_fault() {
                tracing::warn!("{line}");
            } else {
                tracing::info!("{line}");
            }
            let _ = events.send(line);
            self.state = state;
        }
    }

    fn update_status(&mut self, now: Instant, loop_shared: &LoopShared, pipeline: &PipelineShared) {
        let current = Rates {
            at: now,
            ticks: loop_shared.ticks.load(Ordering::Relaxed),
            received: pipeline.received.load(Ordering::Relaxed),
            tracked: pipeline.tracked.load(Ordering::Relaxed),
            detected: pipeline.detected.load(Ordering::Relaxed),
        };
        let span = (current.at - self.rates.at).as_secs_f64().max(1e-3);
        let tracked = current.tracked - self.rates.tracked;
        let detected_pct = if tracked > 0 {
            100.0 * (current.detected - self.rates.detected) as f64 / tracked as f64
        } else {
            0.0
        };
        let mut recording = match self.recording.state() {
            RecordingState::Stopped => format!(" | {}", self.recording.describe()),
            _ => String::new(),
        };
        let unrecorded = self.recording.frames.dropped.load(Ordering::Relaxed);
        if unrecorded > 0 {
            recording.push_str(&format!(" | {unrecorded} frames not recorded"));
        }
        self.status_text = format!(
            "{} | haptic {:.0} Hz, {} overruns | frames {:.1}/s, tracked {:.1}/s, detected {:.0}%, dropped {} | stale events {}, faults {}{recording}",
            self.state.as_str(),
            (current.ticks - self.rates.ticks) as f64 / span,
            loop_shared.overruns.load(Ordering::Relaxed),
            (current.received - self.rates.received) as f64 / span,
            tracked as f64 / span,
            detected_pct,
            pipeline.dropped.load(Ordering::Relaxed) + pipeline.source_dropped.load(Ordering::Relaxed),
            loop_shared.stale_events.load(Ordering::Relaxed),
            loop_shared.faults.load(Ordering::Relaxed),
        );
        self.rates = current;
        self.last_status = now;
        let _ = self.notifier.status(&self.status_text);
    }

    pub fn resend_status(&self) {
        let _ = self.notifier.status(&self.status_text);
    }

    pub fn finish_status_line(&self, status_line: bool) {
        if status_line && self.terminal {
            eprintln!();
        }
    }
}

/// Whether the haptic loop counts as running: `ticks` so far, `since_start` READY,
/// `since_tick` the count last moved.
fn haptic_alive(ticks: u64, since_start: Duration, since_tick: Duration) -> bool {
    if ticks == 0 {
        since_start < LOOP_START_GRACE
    } else {
        since_tick < HAPTIC_SILENCE
    }
}

fn alive(ok: bool) -> &'static str {
    if ok {
        "ok"
    } else {
        "stalled"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loop_is_judged_once_it_has_run() {
        let ms = Duration::from_millis;
        // Not ticked yet, right after READY: preparing, not stalled.
        assert!(haptic_alive(0, ms(0), ms(0)));
        assert!(haptic_alive(0, ms(1500), ms(1500)));
        assert!(!haptic_alive(0, ms(2500), ms(2500)));
        // Two looks a few microseconds apart see the same count: still alive.
        assert!(haptic_alive(5000, ms(5000), ms(0)));
        assert!(haptic_alive(5000, ms(5000), ms(250)));
        assert!(!haptic_alive(5000, ms(5000), ms(400)));
    }

    #[test]
    fn back_to_back_looks_do_not_report_a_stall() {
        let loop_shared = LoopShared::default();
        let pipeline = PipelineShared::default();
        let (events, _rx) = mpsc::channel();
        let mut health = Health::new(Notifier::disabled(), Arc::new(RecordingStatus::default()));
        // Right after READY the loop has not ticked.
        health.check(&loop_shared, &pipeline, &events, false);
        assert!(health.healthy);
        loop_shared.ticks.store(10, Ordering::Relaxed);
        health.check(&loop_shared, &pipeline, &events, false);
        // A burst: the count has not moved between these looks.
        for _ in 0..20 {
            health.check(&loop_shared, &pipeline, &events, false);
            assert!(health.healthy);
        }
        // Really stalled: judged so after HAPTIC_SILENCE.
        std::thread::sleep(HAPTIC_SILENCE + Duration::from_millis(50));
        health.check(&loop_shared, &pipeline, &events, false);
        assert!(!health.healthy);
    }
}
