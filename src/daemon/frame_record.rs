//! Recording the frames the tracker saw, so that a live run can be tracked again
//! (`nanoforce replay SESSION_DIR`).
//!
//! The tracker hands each frame it has tracked to a [`FrameTap`]: the pixels are copied
//! into one of a fixed pool of buffers and queued for the `frame-recorder` thread, which
//! appends them to the session's `frames.nfrm`. The tracker never waits and allocates
//! nothing once every buffer has held a frame: when the writer is behind and no buffer
//! is free, the frame is not recorded and counted as dropped.
//!
//! `frames.nfrm` is the pipe frame source's protocol (see [`crate::hw::frames::pipe`]):
//! per frame the 32-byte `NFRM` header (width, height, the source's sequence number,
//! the capture time in CLOCK_MONOTONIC nanoseconds) and the 8-bit pixels. The session's
//! `session.json` says which CLOCK_MONOTONIC time is t = 0 and its UTC time.
//!
//! Frames take most of a session's bytes: they stop, alone, when the session's frames
//! reach [`FRAMES_SHARE`] of `[daemon] recordings_max_mb` (the telemetry goes on, the
//! stop is logged and counted). A write that fails (a full disk) stops the whole
//! recording, as a telemetry write does.
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use image::GrayImage;

use super::recording::{RecordingState, RecordingStatus};
use crate::hw::frames::pipe::{FrameHeader, HEADER_LEN};
use crate::hw::frames::FrameMeta;
use crate::hw::Clock;

/// The frames file of a session folder.
pub const FRAMES_FILE: &str = "frames.nfrm";
/// Frames queued for the writer at most (about 5 MB of 640 x 480 frames).
pub const QUEUE_FRAMES: usize = 16;
/// The part of `recordings_max_mb` a session's frames may take; the rest is left for
/// its telemetry.
pub const FRAMES_SHARE: f64 = 0.9;

/// One queued frame: its header and pixels (the buffer goes back to the pool).
struct Slot {
    header: FrameHeader,
    pixels: Vec<u8>,
}

/// The tracker's end: offers each tracked frame.
pub struct FrameTap {
    queued: rtrb::Producer<Slot>,
    free: rtrb::Consumer<Slot>,
    clock: Clock,
    status: Arc<RecordingStatus>,
}

impl FrameTap {
    /// Queues a copy of `frame` for recording, or counts it as dropped; never waits.
    pub fn offer(&mut self, frame: &GrayImage, meta: &FrameMeta) {
        let shared = &self.status.frames;
        if shared.stopped.load(Ordering::Relaxed) {
            shared.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let Ok(mut slot) = self.free.pop() else {
            shared.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        };
        slot.header = FrameHeader {
            width: frame.width(),
            height: frame.height(),
            sequence: meta.sequence,
            capture_ns: self.clock.monotonic_ns_at(meta.captured_s),
        };
        slot.pixels.clear();
        slot.pixels.extend_from_slice(frame.as_raw());
        if let Err(rtrb::PushError::Full(_)) = self.queued.push(slot) {
            // Cannot happen (as many places as buffers); counted all the same.
            shared.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The writer thread's inputs.
pub struct FrameWriter {
    pub dir: PathBuf,
    /// Bytes the frames may take (None: no limit).
    pub max_bytes: Option<u64>,
    /// Lines for `events.log`.
    pub events: mpsc::Sender<String>,
}

/// A tap and its writer's end of the queue; both count into `status.frames`.
pub fn frame_channel(clock: Clock, status: Arc<RecordingStatus>) -> (FrameTap, FrameQueue) {
    let (queued_tx, queued_rx) = rtrb::RingBuffer::new(QUEUE_FRAMES);
    let (mut free_tx, free_rx) = rtrb::RingBuffer::new(QUEUE_FRAMES);
    for _ in 0..QUEUE_FRAMES {
        let _ = free_tx.push(Slot {
            header: FrameHeader {
                width: 0,
                height: 0,
                sequence: 0,
                capture_ns: 0,
            },
            pixels: Vec::new(),
        });
    }
    let tap = FrameTap {
        queued: queued_tx,
        free: free_rx,
        clock,
        status: status.clone(),
    };
    let queue = FrameQueue {
        queued: queued_rx,
        free: free_tx,
        status,
    };
    (tap, queue)
}

/// The writer's end of the queue.
pub struct FrameQueue {
    queued: rtrb::Consumer<Slot>,
    free: rtrb::Producer<Slot>,
    status: Arc<RecordingStatus>,
}

/// How long the writer sleeps when the queue is empty.
const IDLE: Duration = Duration::from_millis(5);

/// Starts the `frame-recorder` thread; it writes until `stop` is set, then writes what
/// is queued and ends.
pub fn spawn_frame_writer(
    writer: FrameWriter,
    queue: FrameQueue,
    stop: Arc<AtomicBool>,
) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name("frame-recorder".into())
        .spawn(move || write_frames(writer, queue, &stop))
}

fn write_frames(writer: FrameWriter, mut queue: FrameQueue, stop: &AtomicBool) {
    let path = writer.dir.join(FRAMES_FILE);
    let status = queue.status.clone();
    let shared = &status.frames;
    let mut out = match create(&path) {
        Ok(out) => Some(out),
        Err(e) => {
            shared.stopped.store(true, Ordering::Relaxed);
            status.stop(e.to_string());
            None
        }
    };
    let mut written = 0u64;
    loop {
        let stopping = stop.load(Ordering::Relaxed);
        if out.is_some() && status.state() == RecordingState::Stopped {
            // The telemetry failed or reached the budget: the frames stop with it.
            out = finish(out.take(), &path, &status);
            shared.stopped.store(true, Ordering::Relaxed);
        }
        let mut idle = true;
        while let Ok(slot) = queue.queued.pop() {
            idle = false;
            if let Some(file) = out.as_mut() {
                let size = (HEADER_LEN + slot.pixels.len()) as u64;
                if writer.max_bytes.is_some_and(|max| written + size > max) {
                    let line = format!(
                        "frames: recording stopped after {} frames ({:.1} MB), their share \
                         of daemon.recordings_max_mb; telemetry goes on",
                        shared.recorded.load(Ordering::Relaxed),
                        written as f64 / 1e6
                    );
                    tracing::warn!("{line}");
                    let _ = writer.events.send(line);
                    out = finish(out.take(), &path, &status);
                    shared.stopped.store(true, Ordering::Relaxed);
                } else if let Err(e) = append(file, &slot) {
                    status.stop(format!("{}: {e}", path.display()));
                    shared.stopped.store(true, Ordering::Relaxed);
                    out = None;
                } else {
                    written += size;
                    shared.recorded.fetch_add(1, Ordering::Relaxed);
                    shared.bytes.store(written, Ordering::Relaxed);
                }
            }
            if out.is_none() {
                shared.dropped.fetch_add(1, Ordering::Relaxed);
            }
            let _ = queue.free.push(slot);
        }
        if stopping {
            finish(out, &path, &status);
            return;
        }
        if idle {
            thread::sleep(IDLE);
        }
    }
}

fn create(path: &Path) -> io::Result<BufWriter<File>> {
    File::create(path)
        .map(|f| BufWriter::with_capacity(1 << 20, f))
        .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))
}

fn append(out: &mut impl Write, slot: &Slot) -> io::Result<()> {
    out.write_all(&slot.header.encode())?;
    out.write_all(&slot.pixels)
}

/// Flushes the file; a failure stops the recording. Always None (the file is closed).
fn finish(
    out: Option<BufWriter<File>>,
    path: &Path,
    status: &RecordingStatus,
) -> Option<BufWriter<File>> {
    if let Some(mut out) = out {
        if let Err(e) = out.flush() {
            status.stop(format!("{}: {e}", path.display()));
        }
    }
    None
}

/// The running `frame-recorder` thread.
pub struct FrameRecorder {
    handle: JoinHandle<()>,
    stop: Arc<AtomicBool>,
}

impl FrameRecorder {
    /// Starts recording into `dir/frames.nfrm`; the frames may take `max_bytes`.
    pub fn start(
        writer: FrameWriter,
        clock: Clock,
        status: Arc<RecordingStatus>,
    ) -> io::Result<(FrameTap, FrameRecorder)> {
        let (tap, queue) = frame_channel(clock, status);
        let stop = Arc::new(AtomicBool::new(false));
        let handle = spawn_frame_writer(writer, queue, stop.clone())?;
        Ok((tap, FrameRecorder { handle, stop }))
    }

    /// The thread ended (only a panic ends it before [`FrameRecorder::finish`]).
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Writes what is queued, closes the file and ends the thread, waiting at most
    /// `limit`.
    pub fn finish(self, limit: Duration) {
        self.stop.store(true, Ordering::Relaxed);
        let deadline = std::time::Instant::now() + limit;
        while !self.handle.is_finished() && std::time::Instant::now() < deadline {
            thread::sleep(Duration::from_millis(2));
        }
        if !self.handle.is_finished() {
            tracing::error!("the frame-recorder thread did not end; frames.nfrm may be short");
        } else if self.handle.join().is_err() {
            tracing::error!("the frame-recorder thread panicked; frames.nfrm may be short");
        }
    }
}
