//! The tracker on frames rendered with exact truth (`nanoforce::scene`): the 600-frame
//! suite spanning every condition of docs/renderer.md, blank frames, the paper's grid,
//! sequences with magnification jumps, random order, and calibration against the true
//! edges.
//!
//! Thresholds sit just above the values measured on these seeds (docs/tracker.md), so
//! a regression fails. Run with `cargo test --release --test tracker_rendered`.
mod tracker_support;

use nanoforce::scene::{self, render, Entry, FrameSpec, ProbeGeometry, Session, Setup, Style};
use nanoforce::vision::{Edge, Miss, Pose, Tracker};
use tracker_support::{rendered, score, table, Truth};

/// Subset of frames by style.
fn of_style(
    t: &[Truth],
    e: &[nanoforce::vision::Estimate],
    style: &str,
) -> (Vec<Truth>, Vec<nanoforce::vision::Estimate>) {
    let idx: Vec<usize> = (0..t.len()).filter(|&i| t[i].style == style).collect();
    (
        idx.iter().map(|&i| t[i].clone()).collect(),
        idx.iter().map(|&i| e[i]).collect(),
    )
}

/// The suite seed from `SUITE_SEED`, else `default`.
fn suite_seed(default: u64) -> u64 {
    std::env::var("SUITE_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Writes one row per frame (index, truth detected, detected, look, magnification,
/// signed angle error in deg, the fit's sigma in deg, confidence, true angle) for the
/// multi-suite measurements of docs/tracker-notes.md: `SUITE_DUMP=path.csv`.
fn dump(path: &str, t: &[Truth], e: &[nanoforce::vision::Estimate]) {
    let mut csv = String::new();
    for (i, (t, e)) in t.iter().zip(e).enumerate() {
        let err = e.angle_deg.map_or(f64::NAN, |a| a - t.angle_deg);
        let sigma = e.angle_sigma_deg.unwrap_or(f64::NAN);
        csv += &format!(
            "{i},{},{},{},{},{err},{sigma},{},{}\n",
            u8::from(t.detected),
            u8::from(e.detected),
            t.style,
            t.magnification,
            e.confidence,
            t.angle_deg
        );
    }
    std::fs::write(path, csv).unwrap_or_else(|err| panic!("SUITE_DUMP={path}: {err}"));
}

#[test]
fn suite_of_600_rendered_frames() {
    // 12 sessions x 50 frames: 1000x-8000x, both entry sides, bases within +-35 deg,
    // +-20 deg, the four styles in equal shares, blank frames, 640x480 and 1280x960.
    // Other seeds: SUITE_SEED=n, and SUITE_DUMP=path.csv for every frame's numbers (the
    // thresholds were set on 31; docs/tracker.md has 40 suites, some of which exceed
    // some of them).
    let seed = suite_seed(31);
    let sessions = scene::suite(seed, 12, 50);
    let (t, e) = rendered::run_all(&sessions, false, |_| ());
    let sc = score(&t, &e);
    let why = format!("{sc:?}\n{}", table(&t, &e));
    println!("all: {sc:?}");
    if let Ok(path) = std::env::var("SUITE_DUMP") {
        dump(&path, &t, &e);
    }
    let mut worst: Vec<usize> = (0..t.len())
        .filter(|&i| t[i].detected && e[i].detected)
        .collect();
    let err = |i: usize| (e[i].angle_deg.unwrap_or(f64::NAN) - t[i].angle_deg).abs();
    worst.sort_by(|&a, &b| err(b).total_cmp(&err(a)));
    for &i in worst.iter().take(5) {
        println!(
            "worst: #{i} {} {}x err {:.3} sigma {:.3} conf {:.2}",
            t[i].style,
            t[i].magnification,
            err(i),
            e[i].angle_sigma_deg.unwrap_or(0.0),
            e[i].confidence
        );
    }
    assert_eq!(t.len(), 600);
    assert!(sc.positives >= 550, "{why}");
    assert!(sc.detect_rate >= 0.998, "{why}");
    assert_eq!(sc.false_detections, 0, "{why}");
    // Measured: angle error median 0.0110 deg, p95 0.0735 deg, apex median 0.066 px.
    assert!(sc.angle_err_median_deg <= 0.0115, "{why}");
    assert!(sc.angle_err_p95_deg <= 0.078, "{why}");
    // The worst frames are harsh ones whose error is 2-3 times the fit's own standard
    // error (Estimate::angle_sigma_deg, 0.07-0.1 deg there): noise, not a failure
    // (docs/tracker.md, Accuracy). Measured 0.234 deg.
    assert!(sc.angle_err_max_deg <= 0.25, "{why}");
    assert!(sc.tip_err_median_px <= 0.072, "{why}");
    // Measured (median, p95): clean 0.0039, 0.014; clutter 0.0098, 0.043; noisy
    // 0.0146, 0.049; harsh 0.0277, 0.124. The reported standard error is honest on
    // every look: the RMS of error / sigma (sigma includes the calibration's share, the
    // edges being tied by their calibration errors) measured clean 0.85, clutter 1.04,
    // noisy 0.96, harsh 0.93; with the frame's noise alone as sigma, clean frames
    // would understate their error about twice.
    for (style, median, p95) in [
        ("clean", 0.0042, 0.017),
        ("clutter", 0.0105, 0.045),
        ("noisy", 0.016, 0.052),
        ("harsh", 0.030, 0.125),
    ] {
        let (ts, es) = of_style(&t, &e, style);
        let sc = score(&ts, &es);
        println!("{style}: {sc:?}");
        assert!(
            sc.angle_err_median_deg <= median && sc.angle_err_p95_deg <= p95,
            "{style}: {sc:?}"
        );
        let z: Vec<f64> = ts
            .iter()
            .zip(&es)
            .filter(|(t, e)| t.detected && e.detected)
            .map(|(t, e)| {
                (e.angle_deg.unwrap_or(f64::NAN) - t.angle_deg)
                    / e.angle_sigma_deg.unwrap_or(f64::NAN)
            })
            .collect();
        let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
        println!("{style}: RMS of error / sigma {rms:.2}");
        assert!(
            (0.8..=1.25).contains(&rms),
            "{style}: RMS of error / sigma {rms}"
        );
    }
    for (lo, hi) in [
        (1000.0, 1500.0),
        (1500.0, 2500.0),
        (2500.0, 4000.0),
        (4000.0, 8001.0),
    ] {
        let idx: Vec<usize> = (0..t.len())
            .filter(|&i| (lo..hi).contains(&t[i].magnification))
            .collect();
        let ts: Vec<Truth> = idx.iter().map(|&i| t[i].clone()).collect();
        let es: Vec<_> = idx.iter().map(|&i| e[i]).collect();
        println!("{lo}x-{hi}x: {:?}", score(&ts, &es));
    }
}

#[test]
fn blank_frames_are_never_detected() {
    // The suite's clutter, substrate, shading and noise, without the probe.
    let mut sessions = scene::suite(32, 12, 50);
    let mut max_confidence: f64 = 0.0;
    for s in &mut sessions {
        for f in &mut s.frames {
            f.blank = true;
        }
        let (_, est) = rendered::run(s, true);
        for e in &est {
            assert!(
                !e.detected && e.angle_deg.is_none() && e.force_nn.is_none(),
                "{e:?}"
            );
            max_confidence = max_confidence.max(e.confidence);
        }
    }
    println!("blank frames: largest confidence {max_confidence:.4}");
    assert!(max_confidence < 0.25, "closest call {max_confidence}");
}

#[test]
fn a_line_beside_a_face_does_not_take_its_place() {
    // A harsh frame at 2696x, 1280x960: a scratch runs beside the front face, 8 px
    // outside it, and on past the apex. On the binned edge map it is the longer line,
    // so the search's best tip takes it for the face and puts the apex where it
    // crosses the side face's extension, 24 px too low: 0.74 deg off, at confidence
    // 0.54 (the scratch has a third of the face's contrast). The runner-up on the face
    // itself verifies at 0.84 and must win.
    let session = &scene::suite(12, 12, 50)[8];
    let mut tracker = rendered::tracker(session, false);
    let (frame, truth) = render(&session.frames[47]);
    let e = tracker.track(&frame);
    let (Some(angle), Some(apex)) = (e.angle_deg, e.apex_px) else {
        panic!("not detected: {e:?}");
    };
    let apex_err = (apex[0] - truth.tip_x).hypot(apex[1] - truth.tip_y);
    // Measured: 0.018 deg and 0.23 px.
    assert!(
        (angle - truth.angle_deg).abs() <= 0.05 && apex_err <= 1.0,
        "{angle} for {}, apex {apex:?} for ({}, {})",
        truth.angle_deg,
        truth.tip_x,
        truth.tip_y
    );
}

#[test]
fn a_substrate_beside_part_of_a_face_does_not_lean_it() {
    // A harsh frame at 1578x: the apex dips into the substrate, whose edge crosses both
    // faces a few dozen pixels up, so each face has the bright substrate outside one
    // part and the dark background outside the rest. A single outside level (with a
    // slope) along the face cannot follow that step, and its misfit leans the tip:
    // 0.046 deg off with the noise turned off (0.011 without the substrate), 0.265 deg
    // with it on. Each stretch of a band has its own outside level, which this checks.
    let session = &scene::suite(31, 12, 50)[1];
    let mut tracker = rendered::tracker(session, false);
    let mut spec = session.frames[38];
    let (noisy, truth) = render(&spec);
    spec.look.noise_sigma = 0.0;
    spec.look.jitter_fraction = 0.0;
    let (clean, _) = render(&spec);
    // Measured: 0.003 deg without the noise, 0.164 with it (fit sigma 0.072).
    for (frame, name, limit) in [(&clean, "noise-free", 0.015), (&noisy, "noisy", 0.2)] {
        let e = tracker.track(frame);
        let Some(angle) = e.angle_deg else {
            panic!("{name}: not detected: {e:?}");
        };
        assert!(
            (angle - truth.angle_deg).abs() <= limit,
            "{name}: {angle} for {}",
            truth.angle_deg
        );
    }
}

#[test]
fn harsh_faces_broken_up_on_the_edge_map_are_still_detected() {
    // Two harsh frames at high magnification (7466x and 5640x): Canny on the binned
    // image covers only 52-56 % of the faces, while the grey-level fit holds them
    // (0.67-0.70 of the calibrated contrast). Coverage counted fully only from 65 %
    // would miss them (confidence 0.49).
    let sessions = scene::suite(1, 12, 50);
    for (s, f) in [(6, 1), (9, 46)] {
        let session = &sessions[s];
        let mut tracker = rendered::tracker(session, false);
        let (frame, truth) = render(&session.frames[f]);
        let e = tracker.track(&frame);
        let Some(angle) = e.angle_deg else {
            panic!("session {s} frame {f} not detected: {e:?}");
        };
        // Measured: 0.140 and 0.209 deg (fit sigma 0.078 and 0.129).
        assert!(
            (angle - truth.angle_deg).abs() <= 0.25,
            "session {s} frame {f}: {angle} for {}",
            truth.angle_deg
        );
    }
}

#[test]
fn a_pose_known_from_elsewhere_is_fitted_and_verified_without_a_search() {
    // `Tracker::track_from`, which tells the search's misses from the verification's in
    // the real-background suite: from the true pose, every probe frame of a rendered
    // session verifies where the tracker finds it; moved off the probe the pose is
    // refused, and a pose that is not one (a frame without the probe has no true apex)
    // is refused for it.
    let session = &scene::suite(31, 12, 50)[0];
    let mut tracker = rendered::tracker(session, false);
    let mut verified = 0;
    for spec in session.frames.iter().take(20) {
        let (frame, truth) = render(spec);
        let pose = rendered::true_pose(&truth, &session.reference);
        let found = tracker.track(&frame);
        if !truth.probe_in_view {
            assert!(!found.detected);
            // No true pose: the truth's angle and apex are not numbers.
            let from = tracker.track_from(&frame, pose);
            assert_eq!(from.miss, Some(Miss::ApexOutside), "{from:?}");
            continue;
        }
        let from = tracker.track_from(&frame, pose);
        assert_eq!(from.detected, found.detected, "{found:?}\n{from:?}");
        if let (Some(a), Some(sigma)) = (from.angle_deg, from.angle_sigma_deg) {
            // Fitted from a start the search does not give, it settles within four of its
            // standard errors of the truth (measured: at most 1.5 of them, 0.092 deg).
            verified += 1;
            assert!((a - truth.angle_deg).abs() <= 4.0 * sigma, "{from:?}");
        }
        let off = Pose {
            apex: [pose.apex[0] + 60.0, pose.apex[1] - 60.0],
            ..pose
        };
        let moved = tracker.track_from(&frame, off);
        assert!(!moved.detected, "moved 85 px: {moved:?}");
    }
    // Measured: 19 of the 20 frames show the probe, and all 19 verify.
    assert_eq!(verified, 19);
}

/// A session of the typical probe (like the public samples) with given frames.
fn typical_session(frames: Vec<FrameSpec>) -> Session {
    let setup = Setup {
        probe: ProbeGeometry::typical(),
        width: 640,
        height: 480,
        entry: Entry::Left,
        base_deg: -18.0,
    };
    let mut session = Session::mixed_for(&setup, 5, 1);
    session.frames = frames;
    session
}

#[test]
fn edge_bias_reports_the_true_apex_on_frames_imaged_outside_it() {
    // An SEM that images the probe's outline 0.3 px outside where it is (the public
    // samples' truth reads so): the imaged faces meet 0.3 / sin(half the apex angle)
    // px off the true apex. With tracker.edge_bias_px set to the same 0.3 the apex
    // comes back to the unbiased frames' accuracy; the angles do not move.
    let mut sessions = scene::suite(8, 2, 40);
    let (t0, e0) = rendered::run_all(&sessions, false, |_| ());
    let plain = score(&t0, &e0);
    for s in &mut sessions {
        s.reference.look.edge_bias_px = 0.3;
        for f in &mut s.frames {
            f.look.edge_bias_px = 0.3;
        }
    }
    let (t, imaged) = rendered::run_all(&sessions, false, |_| ());
    let (_, corrected) = rendered::run_all(&sessions, false, |cfg| cfg.edge_bias_px = 0.3);
    let (a, b) = (score(&t, &imaged), score(&t, &corrected));
    let why = format!("no bias rendered: {plain:?}\nedge bias 0: {a:?}\nedge bias 0.3: {b:?}");
    println!("{why}");
    for (x, y) in imaged.iter().zip(&corrected) {
        assert_eq!(x.angle_deg, y.angle_deg, "{why}");
    }
    assert_eq!(b.detect_rate, 1.0, "{why}");
    assert!(a.tip_err_median_px >= 0.5, "{why}");
    assert!(b.tip_err_median_px <= 0.1, "{why}");
    assert!(
        b.tip_err_median_px <= plain.tip_err_median_px + 0.02,
        "{why}"
    );
}

#[test]
fn the_papers_grid_passes_without_coherence() {
    // The paper fails at 20 deg for 2000x and 1500x (its Figure 8 g, k); we must not.
    let mut frames = Vec::new();
    for mag in [3500.0, 2000.0, 1500.0] {
        for angle in [0.0, 5.0, 20.0, -5.0, -20.0] {
            for (k, style) in [Style::Clean, Style::Clutter, Style::Noisy]
                .into_iter()
                .enumerate()
            {
                let mut f = FrameSpec::new(style, angle, 100 + frames.len() as u64);
                f.magnification = mag;
                f.apex_px = [300.0 + 20.0 * k as f64, 250.0];
                frames.push(f);
            }
        }
    }
    let session = typical_session(frames);
    let (t, e) = rendered::run(&session, false);
    let sc = score(&t, &e);
    let why = format!("{sc:?}\n{}", table(&t, &e));
    assert_eq!(sc.detect_rate, 1.0, "{why}");
    assert!(sc.angle_err_max_deg <= 0.1, "{why}");
    assert!(sc.tip_err_median_px <= 0.15, "{why}");
}

#[test]
fn coherence_is_a_shortcut_never_a_dependency() {
    // An operator pressing and releasing, with magnification jumps and the probe now and
    // then out of view; then the same frames shuffled, coherence still on.
    let session = Session::sequence(8, 240, 640, 480);
    let (t, with) = rendered::run(&session, true);
    let (_, without) = rendered::run(&session, false);
    let mut shuffled = session.clone();
    let mut order: Vec<usize> = (0..session.frames.len()).collect();
    let mut rng = scene::rng::Rng::new(9);
    for i in (1..order.len()).rev() {
        order.swap(i, rng.int(0, i as u32) as usize);
    }
    shuffled.frames = order.iter().map(|&i| session.frames[i]).collect();
    let (ts, random) = rendered::run(&shuffled, true);
    assert!(
        t.iter().any(|x| !x.detected),
        "the sequence has blank frames"
    );
    assert!(
        session
            .frames
            .windows(2)
            .filter(|w| w[0].magnification != w[1].magnification)
            .count()
            >= 3
    );
    for (name, truth, est) in [
        ("with", &t, &with),
        ("without", &t, &without),
        ("shuffled", &ts, &random),
    ] {
        let sc = score(truth, est);
        let why = format!("{name}: {sc:?}");
        assert_eq!(sc.detect_rate, 1.0, "{why}");
        assert_eq!(sc.false_detections, 0, "{why}");
        // This sequence is harsh throughout (noise 30, blur 1.5): the hardest look.
        // Measured p95 0.144 (0.146 shuffled) and max 0.266 deg.
        assert!(
            sc.angle_err_p95_deg <= 0.155 && sc.angle_err_max_deg <= 0.28,
            "{why}"
        );
    }
    // Coherence only shortcuts the search: the fit, hence the angle, is the same.
    for (a, b) in with.iter().zip(&without) {
        if let (Some(x), Some(y)) = (a.angle_deg, b.angle_deg) {
            assert!((x - y).abs() < 1e-6, "{x} vs {y}");
        }
    }
}

#[test]
fn calibration_finds_the_true_edges_and_the_reference_reads_zero() {
    // Suite 13's first session: a large pyramid under a beam that leaves the frame at
    // the top close behind the apex, so the frame border cuts the beam's upper face
    // nearer the apex's foot than its free end is: taking the cut for the free end
    // would swap blue and green.
    let mut sessions = scene::suite(33, 6, 1);
    sessions.push(scene::suite(13, 1, 1).remove(0));
    for (i, s) in sessions.iter().enumerate() {
        let (cfg, cal) = rendered::calibrate(s);
        let (reference, truth) = render(&s.reference);
        let edges = truth.edges.expect("reference shows the probe");
        let mut clicked_worst: f64 = 0.0;
        for (edge, seg) in [
            (Edge::Red, edges.red),
            (Edge::Blue, edges.blue),
            (Edge::Green, edges.green),
        ] {
            let c = cal.edge(edge);
            let diff = |a: f64| {
                let d = (a - seg.angle_deg()).rem_euclid(180.0);
                d.min(180.0 - d)
            };
            // The rendered outline (blur, the bright rim, shading) deviates from the
            // geometric edge by up to a few hundredths of a degree in a step fit.
            assert!(
                diff(c.orientation_deg) < 0.04,
                "session {i} {edge}: {} vs {}",
                c.orientation_deg,
                seg.angle_deg()
            );
            clicked_worst = clicked_worst.max(diff(c.clicked_orientation_deg));
        }
        assert!(
            clicked_worst > 0.1,
            "session {i}: clicks alone are off by tenths"
        );
        let apex = cal.apex_px();
        let apex_err = (apex[0] - truth.tip_x).hypot(apex[1] - truth.tip_y);
        assert!(apex_err < 0.15, "session {i}: apex {apex_err} px off");
        let mut tracker = Tracker::new(&cfg, cal, None);
        let e = tracker.track(&reference);
        let angle = e.angle_deg.expect("reference detected");
        assert!(
            angle.abs() < 0.005,
            "session {i}: the reference reads {angle}"
        );
    }
}

#[test]
fn calibration_measures_the_beam_thickness() {
    // The beam's thickness, measured behind the pyramid or, where the beam leaves the
    // reference there, on the overhang in front of it, against the rendered
    // thickness: over the four rendered suites of the confidence table (24
    // references) and the real-background suite (12), 23 and 12 measured, all within
    // 0.70 px (on half-pixel steps). The bound is what the checks reading it tolerate:
    // their samples stand 1.5 blurs and a pixel clear of the lower face.
    let crops = rendered::real_crops();
    let mut sets: Vec<(Vec<Session>, &[image::GrayImage], usize)> = vec![];
    let rendered_suites = [31, 1, 2, 3]
        .iter()
        .flat_map(|&seed| scene::suite(seed, 6, 1))
        .collect();
    sets.push((rendered_suites, &[], 23));
    sets.push((scene::real_suite(71, 12, 50, crops.len()), &crops, 12));
    for (sessions, over, at_least) in sets {
        let mut measured = 0;
        for (i, s) in sessions.iter().enumerate() {
            let (_, cal) = rendered::calibrate_over(s, over);
            let truth = s.reference.probe.thickness_um * s.reference.px_per_um();
            if let Some(px) = cal.beam_px() {
                measured += 1;
                assert!(
                    (px - truth).abs() <= 1.0,
                    "reference {i}: {px} px, truth {truth:.2} px"
                );
            }
        }
        assert!(measured >= at_least, "{measured} of {}", sessions.len());
    }
}

/// CPU time of this thread, seconds (10 ms ticks; immune to other processes' load).
fn thread_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let after = stat.rfind(')').map_or("", |i| &stat[i + 2..]);
    let f: Vec<&str> = after.split(' ').collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// Tracking CPU time per frame on the bench's frames, measured as thread CPU time so
/// that a busy machine does not inflate it (criterion's wall-clock medians do). A
/// measuring tool for docs/tracker.md: `cargo test --release --test tracker_rendered
/// cpu_time -- --ignored --nocapture`. `CPU_TIME_TRACKS=8` tracks each frame 8 times
/// instead of 400, for counting instructions under callgrind (docs/performance.md).
#[test]
#[ignore]
fn cpu_time_per_frame() {
    for width in [640u32, 1280] {
        let setup = Setup {
            probe: ProbeGeometry::typical(),
            width,
            height: width * 3 / 4,
            entry: Entry::Left,
            base_deg: -18.0,
        };
        let session = Session::mixed_for(&setup, 11, 1);
        let (cfg, cal) = rendered::calibrate(&session);
        let mut tracker = Tracker::new(&cfg, cal, Some(setup.probe.cantilever()));
        tracker.set_coherence(false);
        for (name, style, mag, blank) in [
            ("clutter-1000x", Style::Clutter, 1000.0, false),
            ("noisy-2000x", Style::Noisy, 2000.0, false),
            ("harsh-3500x", Style::Harsh, 3500.0, false),
            ("clean-8000x", Style::Clean, 8000.0, false),
            ("blank", Style::Clutter, 2000.0, true),
        ] {
            let mut spec = setup.frame(style, 12.0, mag, 77);
            spec.apex_px = [0.5 * width as f64, 0.55 * setup.height as f64];
            spec.blank = blank;
            let img = render(&spec).0;
            assert_eq!(tracker.track(&img).detected, !blank);
            let n: usize = std::env::var("CPU_TIME_TRACKS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(400);
            let t0 = thread_cpu_s();
            for _ in 0..n {
                std::hint::black_box(tracker.track(&img));
            }
            let ms = (thread_cpu_s() - t0) * 1e3 / n as f64;
            println!("{width}x{} {name}: {ms:.2} ms CPU per frame", setup.height);
        }
    }
}

/// Tracking time per frame over a whole suite (the looks and magnifications the bench
/// does not cover: frames that need runners-up, docs/performance.md), each frame tracked
/// three times and the fastest kept: `SUITE_SEED=12 cargo test --release --test
/// tracker_rendered suite_time -- --ignored --nocapture`.
#[test]
#[ignore]
fn suite_time_per_frame() {
    let seed = suite_seed(12);
    let mut times: Vec<(f64, &'static str, u32)> = Vec::new();
    for session in scene::suite(seed, 12, 50) {
        let mut tracker = rendered::tracker(&session, false);
        let frames: Vec<_> = session.frames.iter().map(|f| render(f).0).collect();
        tracker.track(&frames[0]);
        for (spec, frame) in session.frames.iter().zip(&frames) {
            let fastest = (0..3)
                .map(|_| {
                    let t0 = std::time::Instant::now();
                    std::hint::black_box(tracker.track(frame));
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min);
            times.push((fastest, spec.look.style_name, frame.width()));
        }
    }
    for width in [640, 1280] {
        for style in ["clean", "clutter", "noisy", "harsh", "all"] {
            let mut v: Vec<f64> = times
                .iter()
                .filter(|t| t.2 == width && (style == "all" || t.1 == style))
                .map(|t| t.0)
                .collect();
            v.sort_by(f64::total_cmp);
            let n = v.len();
            println!(
                "{width} {style}: {n} frames, mean {:.3} median {:.3} slowest {:.3} ms",
                v.iter().sum::<f64>() / n as f64,
                v[n / 2],
                v[n - 1]
            );
        }
    }
}
