//! Measurements of a run: fixed-size histograms that record without allocating (the
//! haptic loop and the tracker feed them every tick and frame), and the `--stats-json`
//! report built from them.
use serde::Serialize;

use super::stream::StreamStats;

/// A histogram of non-negative values with fixed-width bins, allocated once.
#[derive(Debug, Clone)]
pub struct Histogram {
    bin_width: f64,
    counts: Vec<u64>,
    overflow: u64,
    count: u64,
    max: f64,
}

impl Histogram {
    /// Bins of `bin_width` from 0 up to `range`; larger values count as overflow.
    pub fn new(bin_width: f64, range: f64) -> Self {
        let bins = (range / bin_width).ceil().max(1.0) as usize;
        Histogram {
            bin_width,
            counts: vec![0; bins],
            overflow: 0,
            count: 0,
            max: 0.0,
        }
    }

    pub fn record(&mut self, value: f64) {
        let value = if value.is_finite() {
            value.max(0.0)
        } else {
            f64::MAX
        };
        let bin = (value / self.bin_width) as usize;
        match self.counts.get_mut(bin) {
            Some(c) => *c += 1,
            None => self.overflow += 1,
        }
        self.count += 1;
        self.max = self.max.max(value);
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    pub fn max(&self) -> f64 {
        self.max
    }

    /// The value below which a fraction `q` of the samples lie (bin centre); `None` when empty.
    pub fn quantile(&self, q: f64) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return Some((i as f64 + 0.5) * self.bin_width);
            }
        }
        Some(self.max)
    }
}

/// Running error of the force estimate against the simulated truth.
#[derive(Debug, Clone, Copy, Default)]
pub struct ForceErrors {
    pub samples: u64,
    pub true_peak_nn: f64,
    sum_sq_nn2: f64,
    pub max_error_nn: f64,
}

impl ForceErrors {
    /// A frame's true force (probe in view), whether or not it was detected.
    pub fn record_truth(&mut self, true_nn: f64) {
        self.true_peak_nn = self.true_peak_nn.max(true_nn.abs());
    }

    /// A detected frame's estimate against its truth.
    pub fn record_error(&mut self, estimate_nn: f64, true_nn: f64) {
        let error = estimate_nn - true_nn;
        self.samples += 1;
        self.sum_sq_nn2 += error * error;
        self.max_error_nn = self.max_error_nn.max(error.abs());
    }

    pub fn rms_error_nn(&self) -> Option<f64> {
        (self.samples > 0).then(|| (self.sum_sq_nn2 / self.samples as f64).sqrt())
    }
}

/// The `--stats-json` report. Field names are part of the interface.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RunStats {
    pub duration_s: f64,
    pub haptic_loop: LoopStats,
    pub frames: FrameStats,
    pub force: ForceStats,
    pub safety: SafetyStats,
    /// Resident memory of the process.
    pub memory: MemoryStats,
    /// How the run ended.
    pub stop: StopStats,
    /// Whether the session folder holds the whole run.
    pub recording: RecordingStats,
    /// The live data stream's datagrams (`[stream]`); null when it is off.
    pub stream: Option<StreamStats>,
    /// Each probe in view, in the configuration's order. `frames.detected` and `force`
    /// above are the first probe's.
    pub probes: Vec<ProbeStats>,
}

/// One probe of the run.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ProbeStats {
    pub name: String,
    pub frames: ProbeFrames,
    /// Its felt force against the simulator's truth (null outside the simulated lab).
    pub force: ForceStats,
}

#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct ProbeFrames {
    /// Frames it was detected in.
    pub detected: u64,
}

/// How the run ended.
#[derive(Debug, Clone, Serialize, PartialEq, Default)]
pub struct StopStats {
    /// "duration", "SIGTERM", "SIGABRT", ..., "requested", "frames ended",
    /// "panic in the tracker thread".
    pub reason: String,
    /// The haptic loop ended, so its outputs were zeroed and forces switched off (false
    /// only when the loop did not end within its deadline).
    pub outputs_zeroed: bool,
}

/// The session recording.
#[derive(Debug, Clone, Serialize, PartialEq, Default)]
pub struct RecordingStats {
    /// "off" (`--no-record`), "recording" (complete), "stopped" (see `error`).
    pub state: String,
    pub error: Option<String>,
    /// Frames written to `frames.nfrm`.
    pub frames_recorded: u64,
    /// Tracked frames not written: the writer was behind (its queue full), or the
    /// frames had stopped (`frames_stopped`, or the recording stopped).
    pub frames_dropped: u64,
    /// The size of `frames.nfrm`, MB (10^6 bytes).
    #[serde(rename = "frames_MB")]
    pub frames_mb: f64,
    /// The frames reached their share of `[daemon] recordings_max_mb` and stopped (the
    /// telemetry went on).
    pub frames_stopped: bool,
}

/// Resident set size, sampled once a second by the supervisor.
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Default)]
pub struct MemoryStats {
    /// At the end of the warm-up (the first 10 s); null for shorter runs.
    pub rss_mb_after_warmup: Option<f64>,
    pub rss_mb_end: Option<f64>,
    pub rss_mb_max: Option<f64>,
}

/// Samples the resident set size: when warm-up ends, the largest, the last.
#[derive(Debug, Clone, Copy, Default)]
pub struct MemoryWatch {
    stats: MemoryStats,
}

/// The warm-up after which memory must stay flat.
pub const WARMUP_S: f64 = 10.0;

impl MemoryWatch {
    pub fn sample(&mut self, elapsed_s: f64) {
        let Some(rss) = resident_mb() else { return };
        let s = &mut self.stats;
        if elapsed_s >= WARMUP_S && s.rss_mb_after_warmup.is_none() {
            s.rss_mb_after_warmup = Some(rss);
        }
        s.rss_mb_end = Some(rss);
        s.rss_mb_max = Some(s.rss_mb_max.map_or(rss, |m| m.max(rss)));
    }

    pub fn stats(&self) -> MemoryStats {
        self.stats
    }
}

/// This process's resident set size in MiB, from /proc/self/statm.
pub fn resident_mb() -> Option<f64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: f64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * page.max(1) as f64 / (1024.0 * 1024.0))
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LoopStats {
    pub ticks: u64,
    pub rate_hz: f64,
    pub period_us_p50: Option<f64>,
    pub period_us_p99: Option<f64>,
    pub period_us_max: Option<f64>,
    pub overruns: u64,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct FrameStats {
    pub received: u64,
    pub tracked: u64,
    pub detected: u64,
    pub dropped: u64,
    pub latency_ms_p50: Option<f64>,
    pub latency_ms_p99: Option<f64>,
}

/// Null outside the simulated lab (no truth to compare with).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ForceStats {
    pub samples: Option<u64>,
    #[serde(rename = "true_peak_nN")]
    pub true_peak_nn: Option<f64>,
    #[serde(rename = "rms_error_nN")]
    pub rms_error_nn: Option<f64>,
    #[serde(rename = "max_error_nN")]
    pub max_error_nn: Option<f64>,
}

impl ForceStats {
    pub fn from_errors(errors: Option<&ForceErrors>) -> Self {
        match errors {
            Some(e) => ForceStats {
                samples: Some(e.samples),
                true_peak_nn: Some(e.true_peak_nn),
                rms_error_nn: e.rms_error_nn(),
                max_error_nn: (e.samples > 0).then_some(e.max_error_nn),
            },
            None => ForceStats {
                samples: None,
                true_peak_nn: None,
                rms_error_nn: None,
                max_error_nn: None,
            },
        }
    }
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SafetyStats {
    pub stale_events: u64,
    pub faults: u64,
    /// Estimates the plausibility gate held (implausible jumps, not rendered).
    pub gate_held: u64,
    /// Estimates rendered attenuated for a large sigma.
    pub gate_attenuated: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_known_distribution() {
        let mut h = Histogram::new(1.0, 2000.0);
        for v in 0..1000 {
            h.record(v as f64);
        }
        h.record(5000.0);
        assert_eq!(h.count(), 1001);
        assert_eq!(h.quantile(0.5), Some(500.5));
        assert_eq!(h.quantile(0.99), Some(990.5));
        assert_eq!(h.max(), 5000.0);
        assert_eq!(Histogram::new(1.0, 10.0).quantile(0.5), None);
    }

    #[test]
    fn force_errors() {
        let mut e = ForceErrors::default();
        e.record_truth(-100.0);
        e.record_error(103.0, 100.0);
        e.record_error(96.0, 100.0);
        assert_eq!(e.true_peak_nn, 100.0);
        assert_eq!(e.max_error_nn, 4.0);
        assert!((e.rms_error_nn().unwrap() - 12.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn json_field_names() {
        let stats = RunStats {
            duration_s: 1.0,
            haptic_loop: LoopStats {
                ticks: 1000,
                rate_hz: 1000.0,
                period_us_p50: Some(1000.5),
                period_us_p99: Some(1010.5),
                period_us_max: Some(1100.0),
                overruns: 0,
            },
            frames: FrameStats {
                received: 60,
                tracked: 60,
                detected: 59,
                dropped: 0,
                latency_ms_p50: Some(1.0),
                latency_ms_p99: Some(2.0),
            },
            force: ForceStats::from_errors(None),
            safety: SafetyStats {
                stale_events: 0,
                faults: 0,
                gate_held: 2,
                gate_attenuated: 0,
            },
            memory: MemoryStats::default(),
            stop: StopStats {
                reason: "SIGABRT".into(),
                outputs_zeroed: true,
            },
            recording: RecordingStats {
                state: "stopped".into(),
                error: Some("No space left on device".into()),
                frames_recorded: 120,
                frames_dropped: 3,
                frames_mb: 36.9,
                frames_stopped: false,
            },
            stream: Some(StreamStats {
                estimates_sent: 59,
                estimates_dropped: 1,
                ..StreamStats::default()
            }),
            probes: vec![ProbeStats {
                name: "left".into(),
                frames: ProbeFrames { detected: 59 },
                force: ForceStats::from_errors(None),
            }],
        };
        let json = serde_json::to_value(&stats).unwrap();
        assert_eq!(json["haptic_loop"]["period_us_p99"], 1010.5);
        assert!(json["force"]["true_peak_nN"].is_null());
        assert_eq!(json["frames"]["dropped"], 0);
        assert_eq!(json["safety"]["gate_held"], 2);
        assert_eq!(json["safety"]["gate_attenuated"], 0);
        assert_eq!(json["stop"]["reason"], "SIGABRT");
        assert_eq!(json["recording"]["state"], "stopped");
        assert_eq!(json["stream"]["estimates_dropped"], 1);
        assert_eq!(json["stream"]["send_errors"], 0);
        assert_eq!(json["recording"]["frames_dropped"], 3);
        assert_eq!(json["recording"]["frames_MB"], 36.9);
        assert_eq!(json["probes"][0]["name"], "left");
        assert_eq!(json["probes"][0]["frames"]["detected"], 59);
        assert!(json["probes"][0]["force"]["rms_error_nN"].is_null());
    }

    #[test]
    fn memory_watch_reads_this_process() {
        let mut watch = MemoryWatch::default();
        watch.sample(1.0);
        let early = watch.stats();
        assert!(early.rss_mb_after_warmup.is_none());
        assert!(early.rss_mb_end.unwrap() > 0.5);
        watch.sample(WARMUP_S + 1.0);
        assert_eq!(watch.stats().rss_mb_after_warmup, watch.stats().rss_mb_end);
    }
}
