//! The AVX2 copies of the tracker's hot loops (`vision::simd`) compute the same
//! estimates and calibrations, to the bit, as the portable ones: what the tracker reports
//! does not depend on the CPU it runs on. On a CPU without AVX2 both runs take the
//! portable loops and the test checks nothing beyond determinism (it says so).
//!
//! One test per binary on purpose: it switches the process-wide choice back and forth.
mod tracker_support;

use image::GrayImage;
use nanoforce::scene::{self, render_tool_into, tool_suite, ToolKind};
use nanoforce::vision::{calibrate_rigid, set_avx2, RigidTracker, Tracker};
use tracker_support::rendered;

/// Debug output round-trips every f64, so equal text means equal bits.
fn bits<T: std::fmt::Debug>(v: &T) -> String {
    format!("{v:?}")
}

#[test]
fn avx2_and_portable_loops_agree_to_the_bit() {
    if !set_avx2(true) {
        println!("this CPU has no AVX2: only the portable loops ran");
    }
    // Four sessions of every style (both frame sizes, both entry sides), 15 frames each.
    let mut frames = 0;
    for session in scene::suite(17, 4, 15) {
        set_avx2(true);
        let (cfg, cal) = rendered::calibrate(&session);
        set_avx2(false);
        let (_, cal_portable) = rendered::calibrate(&session);
        assert_eq!(bits(&cal), bits(&cal_portable));
        let cantilever = Some(session.probe().cantilever());
        let mut fast = Tracker::new(&cfg, cal, cantilever);
        let mut portable = Tracker::new(&cfg, cal_portable, cantilever);
        for spec in &session.frames {
            let (frame, _) = scene::render(spec);
            set_avx2(true);
            let a = fast.track(&frame);
            set_avx2(false);
            let b = portable.track(&frame);
            assert_eq!(bits(&a), bits(&b), "{spec:?}");
            frames += a.detected as usize;
        }
    }
    set_avx2(true);
    assert!(frames >= 50, "only {frames} frames detected");

    // Every rigid tool, searched whole and fitted from the last pose (its stations
    // read by gathers or one pixel at a time).
    let mut tools = 0;
    for kind in ToolKind::ALL {
        let session = &tool_suite(kind, 17, 1, 12, 0)[0];
        let render = |spec| {
            let mut frame = GrayImage::new(1, 1);
            render_tool_into(spec, &[], &mut frame);
            frame
        };
        let clicks: Vec<(String, Vec<[f64; 2]>)> = session
            .clicks
            .iter()
            .map(|(n, p)| (n.to_string(), p.clone()))
            .collect();
        let template = calibrate_rigid(&render(&session.reference), &clicks, session.apex)
            .expect("the rendered reference calibrates");
        let mut fast = RigidTracker::new(template.clone(), 20.0);
        let mut portable = RigidTracker::new(template, 20.0);
        for spec in &session.frames {
            let frame = render(spec);
            set_avx2(true);
            let a = fast.track(&frame);
            set_avx2(false);
            let b = portable.track(&frame);
            assert_eq!(bits(&a), bits(&b), "{} {spec:?}", kind.name());
            tools += a.detected as usize;
        }
    }
    set_avx2(true);
    assert!(tools >= 24, "only {tools} tool frames detected");
}
