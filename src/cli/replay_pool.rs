//! `replay` on every core. The frames are cut into chunks of [`CHUNK_FRAMES`]; each chunk
//! is tracked in order by one thread, with its own trackers (one per probe), after a
//! reset and
//! [`WARMUP_FRAMES`] frames of the previous chunk tracked again without output (the
//! coherence state is the last estimate, so the warm-up rebuilds it). The chunks are the
//! same whatever the number of threads, so the CSVs are byte-identical for `--threads 1`
//! and `--threads N`; the rows are written in frame order as the chunks finish, each
//! probe's into its own CSV.
use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use anyhow::Context;
use image::GrayImage;

use crate::hw::frames::pipe::FrameHeader;
use crate::hw::frames::recording::FrameFile;
use crate::session::frames::load_gray;
use crate::session::metadata::{read_sem_metadata, SemMetadata};
use crate::session::results::{self, FrameLabel, RowExtras};
use crate::session::utc::UtcAnchor;
use crate::vision::{draw_overlays, Estimate, ProbeSet};

/// Frames per chunk: long enough that the warm-up costs little (4 of 120, 3.3 %),
/// short enough that the threads end together (a minute at 20 frames per second is
/// ten chunks: on two cores each tracks five).
pub const CHUNK_FRAMES: usize = 120;
/// Frames before a chunk tracked again to rebuild the tracker's coherence state.
pub const WARMUP_FRAMES: usize = 4;
/// SEM metadata warnings printed in full; later ones are only counted.
const METADATA_WARNINGS_SHOWN: usize = 5;

/// Where the frames come from.
pub enum Frames {
    /// Image files, in order.
    Files(Vec<PathBuf>),
    /// A session's frames file, indexed; the anchor turns capture times into UTC.
    Recorded {
        path: PathBuf,
        frames: Vec<(FrameHeader, u64)>,
        anchor: UtcAnchor,
    },
}

impl Frames {
    pub fn count(&self) -> usize {
        match self {
            Frames::Files(files) => files.len(),
            Frames::Recorded { frames, .. } => frames.len(),
        }
    }
}

/// What one replay needs besides the frames.
pub struct Job<'a> {
    pub frames: &'a Frames,
    /// The overlay file name of each frame (used with `overlay`).
    pub overlay_names: &'a [String],
    pub overlay: Option<&'a std::path::Path>,
    pub timing: bool,
    pub coherence: bool,
}

/// Counts of a replay (or of one chunk).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Counts {
    pub frames: usize,
    /// Per probe, in configuration order.
    pub detected: Vec<usize>,
    pub unreadable: usize,
    pub with_scale: usize,
    pub metadata_warnings: usize,
    pub times_ms: Vec<f64>,
}

impl Counts {
    fn add(&mut self, other: Counts) {
        self.frames += other.frames;
        self.detected
            .resize(other.detected.len().max(self.detected.len()), 0);
        for (sum, n) in self.detected.iter_mut().zip(other.detected) {
            *sum += n;
        }
        self.unreadable += other.unreadable;
        self.with_scale += other.with_scale;
        self.metadata_warnings += other.metadata_warnings;
        self.times_ms.extend(other.times_ms);
    }
}

/// A tracked chunk: its CSV rows (per probe) and counts.
struct Chunk {
    csv: Vec<Vec<u8>>,
    counts: Counts,
}

/// Tracks every frame of `job` on `threads` threads (each with the trackers `probes`
/// makes), writing each probe's rows in frame order into its `out` (one per probe);
/// `done` is called with the number of frames of each chunk written.
pub fn replay_frames<W: Write>(
    job: &Job,
    threads: usize,
    probes: &(dyn Fn() -> anyhow::Result<ProbeSet> + Sync),
    out: &mut [W],
    done: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Counts> {
    let chunks = job.frames.count().div_ceil(CHUNK_FRAMES);
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let warned = AtomicUsize::new(0);
    let (tx, rx) = mpsc::channel::<(usize, anyhow::Result<Chunk>)>();
    std::thread::scope(|scope| -> anyhow::Result<Counts> {
        for _ in 0..threads.clamp(1, chunks.max(1)) {
            let tx = tx.clone();
            let (next, failed, warned) = (&next, &failed, &warned);
            scope.spawn(move || {
                let mut tracker = match probes() {
                    Ok(t) => t,
                    Err(e) => {
                        failed.store(true, Ordering::Relaxed);
                        let _ = tx.send((usize::MAX, Err(e)));
                        return;
                    }
                };
                tracker.set_coherence(job.coherence);
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= chunks || failed.load(Ordering::Relaxed) {
                        return;
                    }
                    let chunk = track_chunk(&mut tracker, job, index, warned);
                    if chunk.is_err() {
                        failed.store(true, Ordering::Relaxed);
                    }
                    if tx.send((index, chunk)).is_err() {
                        return;
                    }
                }
            });
        }
        drop(tx);
        let mut waiting = BTreeMap::new();
        let mut written = 0;
        let mut counts = Counts::default();
        for (index, chunk) in rx {
            waiting.insert(index, chunk?);
            while let Some(chunk) = waiting.remove(&written) {
                for (out, rows) in out.iter_mut().zip(&chunk.csv) {
                    out.write_all(rows)?;
                }
                done(chunk.counts.frames);
                counts.add(chunk.counts);
                written += 1;
            }
        }
        Ok(counts)
    })
}

/// Tracks chunk `index`: a reset, the warm-up frames (no output), then its frames.
fn track_chunk(
    tracker: &mut ProbeSet,
    job: &Job,
    index: usize,
    warned: &AtomicUsize,
) -> anyhow::Result<Chunk> {
    let start = index * CHUNK_FRAMES;
    let end = (start + CHUNK_FRAMES).min(job.frames.count());
    let from = if job.coherence {
        start.saturating_sub(WARMUP_FRAMES)
    } else {
        start
    };
    let file = match job.frames {
        Frames::Recorded { path, .. } => {
            Some(File::open(path).with_context(|| format!("opening {}", path.display()))?)
        }
        Frames::Files(_) => None,
    };
    tracker.reset();
    let probes = tracker.len();
    let mut chunk = Chunk {
        csv: vec![Vec::new(); probes],
        counts: Counts {
            detected: vec![0; probes],
            ..Counts::default()
        },
    };
    let mut estimates = vec![Estimate::default(); probes];
    let mut image = GrayImage::new(0, 0);
    for i in from..end {
        let output = i >= start;
        let (loaded, name, seq, utc, time_s, path) = match job.frames {
            Frames::Files(files) => {
                let path = &files[i];
                let name = path
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().to_string());
                let loaded = load_gray(path)
                    .map(|img| image = img)
                    .map_err(|e| e.to_string());
                (loaded, name, i as u64 + 1, String::new(), None, Some(path))
            }
            Frames::Recorded {
                path,
                frames,
                anchor,
            } => {
                let (header, offset) = &frames[i];
                let raw = file.as_ref().context("the frames file")?;
                let loaded = FrameFile::read_at(raw, header, *offset, &mut image)
                    .map_err(|e| format!("{}: frame {}: {e}", path.display(), header.sequence));
                let time_s = match header.capture_ns {
                    0 => None,
                    ns => Some(anchor.seconds_at(ns)),
                };
                (
                    loaded,
                    header.sequence.to_string(),
                    header.sequence,
                    time_s.map_or_else(String::new, |t| anchor.utc(t)),
                    time_s,
                    None,
                )
            }
        };
        let label = FrameLabel {
            name: &name,
            seq,
            utc: &utc,
            time_s,
        };
        if let Err(e) = &loaded {
            // Coherence must not carry over a gap in the sequence.
            tracker.reset();
            if output {
                tracing::warn!("{e}; recorded as not detected");
                chunk.counts.frames += 1;
                chunk.counts.unreadable += 1;
                for csv in &mut chunk.csv {
                    results::write_unreadable(csv, &label)?;
                }
            }
            continue;
        }
        let started = Instant::now();
        tracker.track(&image, &mut estimates);
        let ms = started.elapsed().as_secs_f64() * 1e3;
        if !output {
            continue;
        }
        let sem = match path {
            Some(path) => frame_metadata(path, &mut chunk.counts, warned),
            None => SemMetadata::default(),
        };
        chunk.counts.frames += 1;
        chunk.counts.times_ms.push(ms);
        let extras = RowExtras {
            processing_ms: job.timing.then_some(ms),
            ..RowExtras::default()
        };
        for (p, estimate) in estimates.iter().enumerate() {
            chunk.counts.detected[p] += usize::from(estimate.detected);
            let origin = tracker.trackers()[p].pixel_origin();
            let written = estimate.with_pixel_origin(origin);
            results::write_row(&mut chunk.csv[p], &label, &written, &sem, &extras)?;
        }
        if let Some(dir) = job.overlay {
            let out = dir.join(&job.overlay_names[i]);
            draw_overlays(&image, &estimates)
                .save(&out)
                .with_context(|| format!("writing {}", out.display()))?;
        }
    }
    Ok(chunk)
}

/// The SEM metadata of one frame; problems are warned about (the first few in full) and
/// counted.
fn frame_metadata(
    path: &std::path::Path,
    counts: &mut Counts,
    warned: &AtomicUsize,
) -> SemMetadata {
    let sem = read_sem_metadata(path);
    counts.with_scale += usize::from(sem.pixel_size_um.is_some());
    if !sem.warnings.is_empty() {
        counts.metadata_warnings += 1;
        if warned.fetch_add(1, Ordering::Relaxed) < METADATA_WARNINGS_SHOWN {
            let text = sem.warnings.join("; ");
            tracing::warn!("{}: SEM metadata: {text}", path.display());
        }
    }
    sem
}
