//! The tracker's window for people: what the live monitor page and the recorded
//! thumbnails are drawn from, without ever slowing the tracker.
//!
//! The tracker thread holds a [`SnapshotTap`]. Every published estimate goes into a
//! wait-free ring (dropped when the ring is full: the reader is late, never the tracker);
//! at most `frame_hz` times a second the frame, its estimate and the found edge segments
//! are copied into a triple buffer (latest only). Both are allocation-free after the
//! first frame of a size; all drawing and encoding happen on the reader's thread.
use image::GrayImage;

use crate::control::Published;
use crate::vision::{Estimate, MAX_PROBES};

/// Ring size: ten seconds of estimates at 100 frames per second.
const ESTIMATE_RING: usize = 1024;

/// One frame as the tracker saw it, with each probe's estimate (edges included).
#[derive(Debug, Clone)]
pub struct FrameSnapshot {
    pub image: GrayImage,
    /// The first `probes` hold the estimates, in the probes' order.
    estimates: [Published; MAX_PROBES],
    probes: usize,
}

impl Default for FrameSnapshot {
    fn default() -> Self {
        FrameSnapshot {
            image: GrayImage::new(0, 0),
            estimates: [Published::default(); MAX_PROBES],
            probes: 0,
        }
    }
}

impl FrameSnapshot {
    /// Each probe's estimate, in order.
    pub fn estimates(&self) -> &[Published] {
        &self.estimates[..self.probes]
    }

    /// Each probe's tracker estimate, in order (for drawing).
    pub fn tracked(&self) -> impl Iterator<Item = Estimate> + '_ {
        self.estimates().iter().map(|p| p.estimate)
    }
}

/// The tracker's end.
pub struct SnapshotTap {
    frames: triple_buffer::Input<FrameSnapshot>,
    estimates: rtrb::Producer<Published>,
    every_s: f64,
    next_s: f64,
}

/// The reader's end (the monitor thread).
pub struct SnapshotReader {
    pub frames: triple_buffer::Output<FrameSnapshot>,
    pub estimates: rtrb::Consumer<Published>,
}

/// A tap that copies frames at most `frame_hz` times a second, and its reader.
pub fn snapshot_channel(frame_hz: f64) -> (SnapshotTap, SnapshotReader) {
    let (frames_in, frames_out) = triple_buffer::triple_buffer(&FrameSnapshot::default());
    let (est_tx, est_rx) = rtrb::RingBuffer::new(ESTIMATE_RING);
    let tap = SnapshotTap {
        frames: frames_in,
        estimates: est_tx,
        every_s: 1.0 / frame_hz.clamp(0.01, 10.0),
        next_s: f64::NEG_INFINITY,
    };
    let reader = SnapshotReader {
        frames: frames_out,
        estimates: est_rx,
    };
    (tap, reader)
}

impl SnapshotTap {
    /// Offers one tracked frame at `now_s`; never blocks, allocates only when the frame
    /// size changes.
    /// `estimates`: each probe's, in order (at most [`MAX_PROBES`]).
    pub fn offer(&mut self, now_s: f64, image: &GrayImage, estimates: &[Published]) {
        for estimate in estimates {
            let _ = self.estimates.push(*estimate);
        }
        if now_s < self.next_s {
            return;
        }
        // Keep the cadence; after a pause start afresh rather than catch up in a burst.
        self.next_s = if now_s - self.next_s > self.every_s {
            now_s + self.every_s
        } else {
            self.next_s + self.every_s
        };
        let slot = self.frames.input_buffer_mut();
        copy_frame(&mut slot.image, image);
        let probes = estimates.len().min(MAX_PROBES);
        slot.estimates[..probes].copy_from_slice(&estimates[..probes]);
        slot.probes = probes;
        self.frames.publish();
    }
}

/// Copies `src` into `dst`, reusing `dst`'s buffer when the sizes match.
fn copy_frame(dst: &mut GrayImage, src: &GrayImage) {
    if dst.dimensions() == src.dimensions() {
        dst.copy_from_slice(src.as_raw());
    } else {
        dst.clone_from(src);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_thinned_and_estimates_kept() {
        let (mut tap, mut reader) = snapshot_channel(5.0);
        let mut image = GrayImage::new(8, 4);
        let edge = crate::vision::EdgeFit {
            start_px: [1.0, 2.0],
            end_px: [3.0, 4.0],
            support: 9,
            contrast: 40.0,
        };
        for k in 0..30u64 {
            image.put_pixel(0, 0, image::Luma([k as u8]));
            let mut e = Published {
                seq: k + 1,
                ..Published::default()
            };
            e.estimate.edges[0] = Some(edge);
            tap.offer(k as f64 / 60.0, &image, &[e]);
            if k == 0 {
                assert!(reader.frames.update(), "the first frame is copied at once");
                assert_eq!(
                    reader.frames.output_buffer_mut().image.get_pixel(0, 0)[0],
                    0
                );
            }
        }
        assert_eq!(
            reader.estimates.slots(),
            30,
            "every estimate reaches the ring"
        );
        assert!(reader.frames.update());
        let last = reader.frames.output_buffer_mut();
        // 30 frames at 60 Hz = 0.5 s: copies at 0, 0.2 and 0.4 s (frame 24).
        assert_eq!(last.estimates()[0].seq, 25);
        assert_eq!(last.image.get_pixel(0, 0)[0], 24);
        let edges = &last.estimates()[0].estimate.edges;
        assert_eq!(edges[0], Some(edge));
        assert!(edges[1..].iter().all(Option::is_none));
    }

    #[test]
    fn a_full_ring_drops_instead_of_blocking() {
        let (mut tap, reader) = snapshot_channel(1.0);
        let image = GrayImage::new(2, 2);
        for _ in 0..ESTIMATE_RING + 10 {
            tap.offer(0.0, &image, &[Published::default()]);
        }
        assert_eq!(reader.estimates.slots(), ESTIMATE_RING);
    }
}
