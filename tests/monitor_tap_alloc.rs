//! The tracker's side of the monitor must not allocate once warm: after the first copy of
//! a frame size into each of the triple buffer's slots, offering frames and estimates
//! allocates nothing (a counting allocator counts this thread's allocations).
use image::GrayImage;
use nanoforce::control::Published;
use nanoforce::daemon::snapshot::snapshot_channel;
use nanoforce::vision::EdgeFit;

mod alloc_counter;

#[global_allocator]
static GLOBAL: alloc_counter::Counting = alloc_counter::Counting;

#[test]
fn offering_snapshots_does_not_allocate_after_warm_up() {
    let (mut tap, mut reader) = snapshot_channel(10.0);
    let frame = GrayImage::new(640, 480);
    // An estimate with an edge, as the monitor draws it.
    let mut estimate = Published::default();
    estimate.estimate.edges[0] = Some(EdgeFit {
        start_px: [1.0, 2.0],
        end_px: [3.0, 4.0],
        support: 9,
        contrast: 40.0,
    });
    let mut t = 0.0;
    let mut offer = |tap: &mut nanoforce::daemon::snapshot::SnapshotTap, n: usize| {
        for _ in 0..n {
            t += 1.0 / 60.0;
            tap.offer(t, &frame, &[estimate]);
        }
    };
    // Warm-up: the reader takes frames as the monitor would, so every slot is used.
    for _ in 0..6 {
        offer(&mut tap, 6);
        reader.frames.update();
        while reader.estimates.pop().is_ok() {}
    }
    alloc_counter::watch_this_thread();
    alloc_counter::start();
    for _ in 0..20 {
        offer(&mut tap, 6);
    }
    assert_eq!(alloc_counter::stop(), 0, "allocations in 120 offers");
    assert!(reader.frames.update(), "and frames still arrive");
    assert_eq!(reader.frames.output_buffer_mut().image.width(), 640);
}
