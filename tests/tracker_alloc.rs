//! Tracking allocates nothing per frame after warm-up: a counting global allocator in
//! this test binary of its own watches frames of both sizes, busy and blank, with and
//! without coherence.
use image::GrayImage;
use nanoforce::scene::{self, render_into};
use nanoforce::vision::{Estimate, ProbeSet, Tracker, SECOND_TRACKING_THREAD};

mod tracker_support;

mod alloc_counter;

#[global_allocator]
static GLOBAL: alloc_counter::Counting = alloc_counter::Counting;

/// The count is one for the whole binary: its tests take turns, or one would count the
/// other's allocations.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn turn() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn tracking_allocates_nothing_after_warm_up() {
    let _turn = turn();
    alloc_counter::watch_this_thread();
    // One 640x480 and one 1280x960 session of the suite, frames rendered up front.
    let sessions = scene::suite(41, 3, 24);
    for session in [&sessions[0], &sessions[2]] {
        let (cfg, cal) = tracker_support::rendered::calibrate(session);
        let mut frames = Vec::new();
        for (k, spec) in session.frames.iter().enumerate() {
            let mut spec = *spec;
            spec.blank |= k % 7 == 3;
            let mut frame = GrayImage::new(1, 1);
            render_into(&spec, &mut frame);
            frames.push(frame);
        }
        let mut tracker = Tracker::new(&cfg, cal, Some(session.probe().cantilever()));
        // Warm-up: one frame sizes every buffer for this frame size.
        tracker.track(&frames[0]);
        let mut detected = 0;
        for coherence in [true, false] {
            tracker.set_coherence(coherence);
            alloc_counter::start();
            for frame in &frames {
                detected += tracker.track(frame).detected as usize;
            }
            let n = alloc_counter::stop();
            assert_eq!(
                n,
                0,
                "{n} allocations over {} frames of {}x{}",
                frames.len(),
                frames[0].width(),
                frames[0].height()
            );
        }
        assert!(
            detected > frames.len(),
            "frames were really tracked: {detected}"
        );
    }
}

#[test]
fn tracking_several_probes_allocates_nothing_after_warm_up() {
    let _turn = turn();
    alloc_counter::watch_this_thread();
    alloc_counter::watch_threads_named(SECOND_TRACKING_THREAD);
    let session = scene::Session::several(41, 2, 24, 640, 480);
    let frames: Vec<GrayImage> = session.frames.iter().map(|f| scene::render(f).0).collect();
    for threads in [1, 2] {
        let trackers = session
            .trackers()
            .expect("the rendered reference calibrates");
        let mut set = ProbeSet::new(trackers, &[0, 0]);
        if threads == 2 {
            set = set.on_two_threads().expect("a second thread starts");
        }
        let mut out = vec![Estimate::default(); 2];
        set.track(&frames[0], &mut out);
        alloc_counter::start();
        let mut detected = 0;
        for frame in &frames {
            set.track(frame, &mut out);
            detected += out.iter().filter(|e| e.detected).count();
        }
        let n = alloc_counter::stop();
        assert_eq!(
            n,
            0,
            "{n} allocations over {} frames on {threads} threads",
            frames.len()
        );
        assert!(
            detected > frames.len(),
            "frames were really tracked: {detected}"
        );
    }
}
