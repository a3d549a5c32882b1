//! The monitor's producer, stepped every [`super::UPDATE_PERIOD`] on the monitor thread:
//! drains the tracker's estimates into the force history, takes the newest frame
//! snapshot (draws its overlay for the page, keeps a thumbnail for the recording), turns
//! the loops' counters into rates, and hands one JSON update to every live page.
use std::collections::VecDeque;
use std::io::Cursor;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use image::{GrayImage, ImageFormat, RgbImage};
use serde_json::json;

use super::server::Hub;
use super::DaemonView;
use crate::daemon::inject::PanicInjection;
use crate::daemon::snapshot::SnapshotReader;
use crate::report::thumbs::{overlay_at_width, THUMB_WIDTH};
use crate::vision::Estimate;

/// Seconds of force history a new page starts with.
const HISTORY_S: f64 = 30.0;
/// Widest overlay the page gets, pixels.
const PAGE_FRAME_WIDTH: u32 = 800;
/// Most thumbnails a recording keeps: past it, every other one goes and the interval
/// doubles, so a day-long run stays small.
const MAX_THUMBNAILS: usize = 240;

pub struct Producer {
    reader: SnapshotReader,
    view: DaemonView,
    hub: Arc<Hub>,
    serve: bool,
    history: VecDeque<[f64; 2]>,
    fresh: Vec<[f64; 2]>,
    frame: Option<serde_json::Value>,
    rates: Rates,
    thumbnails: Option<Thumbnails>,
    steps: u64,
}

/// Counters at the last rate computation.
struct Rates {
    at: Instant,
    counts: [u64; 4],
    json: serde_json::Value,
}

impl Producer {
    pub fn new(
        reader: SnapshotReader,
        view: DaemonView,
        hub: Arc<Hub>,
        thumbnails: Option<(PathBuf, f64)>,
        serve: bool,
    ) -> Self {
        Producer {
            reader,
            view,
            hub,
            serve,
            history: VecDeque::new(),
            fresh: Vec::new(),
            frame: None,
            rates: Rates {
                at: Instant::now(),
                counts: [0; 4],
                json: serde_json::Value::Null,
            },
            thumbnails: thumbnails.map(|(dir, every_s)| Thumbnails::new(dir, every_s)),
            steps: 0,
        }
    }

    /// One update.
    pub fn step(&mut self) {
        PanicInjection::check(self.view.inject.as_ref(), "monitor");
        self.steps += 1;
        // The force history is the felt probe's.
        let active = self.view.loop_shared.active_probe();
        while let Ok(e) = self.reader.estimates.pop() {
            if e.probe == active {
                let force = e.estimate.felt_force_nn().unwrap_or(f64::NAN);
                self.fresh.push([e.frame_time_s, force]);
            }
        }
        if self.reader.frames.update() && self.reader.frames.output_buffer_mut().image.width() > 0 {
            self.take_frame();
        }
        self.update_rates();
        if self.serve {
            self.publish();
        }
        let newest = self.fresh.last().map(|p| p[0]);
        self.history.extend(self.fresh.drain(..));
        if let Some(t) = newest {
            while self.history.front().is_some_and(|p| p[0] < t - HISTORY_S) {
                self.history.pop_front();
            }
        }
    }

    /// The newest frame: the first probe's numbers at the top level, and every probe's
    /// (named, the felt one marked) under `probes`.
    fn take_frame(&mut self) {
        let snapshot = self.reader.frames.output_buffer_mut();
        let Some(p) = snapshot.estimates().first() else {
            return;
        };
        let active = self.view.loop_shared.active_probe();
        let numbers = |estimate: &Estimate| {
            json!({
                "detected": estimate.detected,
                "felt": estimate.felt_force_nn().is_some(),
                "angle_deg": estimate.shown(estimate.angle_deg),
                "force_nn": estimate.shown(estimate.force_nn),
                "confidence": estimate.confidence,
            })
        };
        let probes: Vec<serde_json::Value> = snapshot
            .estimates()
            .iter()
            .map(|q| {
                let mut entry = numbers(&q.estimate);
                entry["name"] = json!(self.view.probe_names.get(q.probe));
                entry["active"] = json!(q.probe == active);
                entry
            })
            .collect();
        let mut frame = numbers(&p.estimate);
        frame["seq"] = json!(p.frame_sequence);
        frame["t"] = json!(p.frame_time_s);
        frame["width"] = json!(snapshot.image.width());
        frame["height"] = json!(snapshot.image.height());
        frame["probes"] = json!(probes);
        let sequence = p.frame_sequence;
        self.frame = Some(frame);
        let estimates: Vec<Estimate> = snapshot.tracked().collect();
        if self.serve {
            let width = snapshot.image.width().min(PAGE_FRAME_WIDTH);
            if let Some(png) = png(&overlay_at_width(&snapshot.image, &estimates, width)) {
                self.hub.set_frame(png);
            }
        }
        if let Some(thumbnails) = &mut self.thumbnails {
            thumbnails.offer(&snapshot.image, &estimates, sequence);
        }
    }

    fn update_rates(&mut self) {
        let now = Instant::now();
        let span = (now - self.rates.at).as_secs_f64();
        if span < 1.0 && !self.rates.json.is_null() {
            return;
        }
        let l = &self.view.loop_shared;
        let p = &self.view.pipeline_shared;
        let counts = [
            l.ticks.load(Ordering::Relaxed),
            p.received.load(Ordering::Relaxed),
            p.tracked.load(Ordering::Relaxed),
            p.detected.load(Ordering::Relaxed),
        ];
        let d: Vec<f64> = counts
            .iter()
            .zip(self.rates.counts)
            .map(|(now, then)| now.saturating_sub(then) as f64)
            .collect();
        let span = span.max(1e-3);
        self.rates = Rates {
            at: now,
            counts,
            json: json!({
                "haptic_hz": d[0] / span,
                "frames_hz": d[1] / span,
                "tracked_hz": d[2] / span,
                "detected_pct": if d[2] > 0.0 { 100.0 * d[3] / d[2] } else { 0.0 },
            }),
        };
    }

    fn publish(&mut self) {
        let l = &self.view.loop_shared;
        let p = &self.view.pipeline_shared;
        let state = l.state();
        let update = json!({
            "force": self.fresh,
            "state": state.as_str(),
            "fault": state.is_fault(),
            "recording": self.view.recording.state().as_str(),
            "recording_error": self.view.recording.error(),
            "recording_frames_dropped": self.view.recording.frames.dropped.load(Ordering::Relaxed),
            "rates": self.rates.json,
            "counters": {
                "overruns": l.overruns.load(Ordering::Relaxed),
                "dropped_frames": p.dropped.load(Ordering::Relaxed)
                    + p.source_dropped.load(Ordering::Relaxed),
                "stale_events": l.stale_events.load(Ordering::Relaxed),
                "faults": l.faults.load(Ordering::Relaxed),
                "gate_held": l.gate_held.load(Ordering::Relaxed),
                "gate_attenuated": l.gate_attenuated.load(Ordering::Relaxed),
                "frame_period_ms": l.frame_period_us.load(Ordering::Relaxed) as f64 * 1e-3,
                "slow_frames": l.slow_frames.load(Ordering::Relaxed),
            },
            "stream": self.view.stream.as_ref().map(|s| s.stats()),
            "frame": self.frame,
            "clients": self.hub.clients(),
            "dropped_updates": self.hub.dropped_updates.load(Ordering::Relaxed),
        });
        self.hub.broadcast(&update.to_string());
        // A new page starts from the history; refreshing it twice a second is plenty.
        if self.steps.is_multiple_of(5) {
            let history: Vec<[f64; 2]> = self.history.iter().chain(&self.fresh).copied().collect();
            self.hub
                .set_hello(json!({ "force": history, "history_s": HISTORY_S }).to_string());
        }
    }
}

fn png(image: &RgbImage) -> Option<Vec<u8>> {
    let mut out = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut out), ImageFormat::Png)
        .ok()?;
    Some(out)
}

/// The recording's `thumbnails/` folder.
struct Thumbnails {
    dir: PathBuf,
    every_s: f64,
    next: Instant,
    written: Vec<PathBuf>,
    failed: bool,
}

impl Thumbnails {
    fn new(dir: PathBuf, every_s: f64) -> Self {
        Thumbnails {
            dir,
            every_s,
            next: Instant::now(),
            written: Vec::new(),
            failed: false,
        }
    }

    fn offer(&mut self, frame: &GrayImage, estimates: &[Estimate], sequence: u64) {
        let now = Instant::now();
        if self.failed || now < self.next {
            return;
        }
        self.next = now + std::time::Duration::from_secs_f64(self.every_s);
        let path = self.dir.join(format!("frame_{sequence:07}.png"));
        let written = std::fs::create_dir_all(&self.dir)
            .map_err(|e| e.to_string())
            .and_then(|()| {
                overlay_at_width(frame, estimates, THUMB_WIDTH)
                    .save(&path)
                    .map_err(|e| e.to_string())
            });
        if let Err(e) = written {
            tracing::warn!("{}: {e}; no more thumbnails this run", path.display());
            self.failed = true;
            return;
        }
        self.written.push(path);
        if self.written.len() >= MAX_THUMBNAILS {
            let mut keep = Vec::with_capacity(MAX_THUMBNAILS / 2 + 1);
            for (k, p) in self.written.drain(..).enumerate() {
                if k % 2 == 0 {
                    keep.push(p);
                } else {
                    let _ = std::fs::remove_file(&p);
                }
            }
            self.written = keep;
            self.every_s *= 2.0;
        }
    }
}
