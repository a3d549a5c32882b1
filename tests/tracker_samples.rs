//! The tracker on the two public sample sessions, scored against their truth the way
//! `nanoforce score` does, plus calibration on their reference images.
//!
//! Thresholds sit just above the measured values (docs/tracker.md), so a regression fails.
//! Where their own image content puts the apex, the samples' truth is about (+0.6, -0.15)
//! px away: a pixel-corner origin plus 0.65 px up the pyramid's axis, turning with the tip
//! (docs/tracker.md, Public samples; an independent least-squares fit agrees with the
//! tracker, and the rendered suite, with exact truth, shows 0.08 px). With the default
//! convention (docs/conventions.md) the apex thresholds allow for that offset rather than
//! hiding it; with the samples' convention (`pixel_origin` and an `edge_bias_px` measured
//! on the other session) the apex meets 0.5 px with room.
mod tracker_support;

use image::Rgb;
use nanoforce::config::PixelOrigin;
use nanoforce::vision::{
    draw_calibration, draw_overlay, Calibration, Edge, Estimate, Miss, ScaleRange, Tracker,
    TrackerConfig, VisionError,
};
use tracker_support::{angle_rms_deg, percentile, result_csv, sample, score, table, Session};

#[test]
fn mixed_sample_in_random_order() {
    let s = sample("mixed");
    let est = s.run(false);
    let sc = score(&s.truth, &est);
    let why = format!("{sc:?}\n{}", table(&s.truth, &est));
    assert_eq!(sc.detect_rate, 1.0, "{why}");
    assert_eq!(sc.false_detections, 0, "{why}");
    // Measured: angle error median 0.0296 deg, p95 0.0967, max 0.221, RMS 0.0599 deg,
    // apex median 0.66 px. The median of these 30 frames is the mean of the 15th and
    // 16th errors, and a change that lowers most frames' errors can move it by a few
    // ten-thousandths either way: the median is held within 0.001 deg of the 0.03 deg
    // target, the RMS to its measured value.
    assert!(sc.angle_err_median_deg <= 0.031, "{why}");
    assert!(sc.angle_err_p95_deg <= 0.10, "{why}");
    assert!(sc.angle_err_max_deg <= 0.235, "{why}");
    assert!(angle_rms_deg(&s.truth, &est) <= 0.061, "{why}");
    assert!(sc.tip_err_median_px <= 0.7, "{why}");
}

#[test]
fn sequence_sample_with_and_without_coherence() {
    let s = sample("sequence");
    for coherence in [true, false] {
        let est = s.run(coherence);
        let sc = score(&s.truth, &est);
        let why = format!("coherence {coherence}: {sc:?}\n{}", table(&s.truth, &est));
        assert_eq!(sc.detect_rate, 1.0, "{why}");
        // Measured: angle error median 0.0196 deg, p95 0.0542, max 0.081, apex median
        // 0.555 px.
        assert!(sc.angle_err_median_deg <= 0.020, "{why}");
        assert!(sc.angle_err_p95_deg <= 0.058, "{why}");
        assert!(sc.angle_err_max_deg <= 0.085, "{why}");
        assert!(sc.tip_err_median_px <= 0.6, "{why}");
    }
}

/// Each probe frame's apex as written with `pixel_origin = "corner"`: at no edge bias,
/// and its shift per pixel of `edge_bias_px` (the shift is linear in the bias).
fn corner_apexes(s: &Session) -> Vec<Option<([f64; 2], [f64; 2])>> {
    let at = |bias: f64| {
        let mut cfg = s.config.probes[0].tracker.clone();
        cfg.pixel_origin = PixelOrigin::Corner;
        cfg.edge_bias_px = bias;
        s.run_with(&cfg, false)
            .into_iter()
            .map(|e| e.with_pixel_origin(cfg.pixel_origin).apex_px)
            .collect::<Vec<_>>()
    };
    let (zero, one) = (at(0.0), at(1.0));
    s.truth
        .iter()
        .zip(zero.iter().zip(&one))
        .map(|(t, (a, b))| match (t.detected, a, b) {
            (true, Some(a), Some(b)) => Some((*a, [b[0] - a[0], b[1] - a[1]])),
            _ => None,
        })
        .collect()
}

/// The edge bias that best explains `s`'s apex truth (least squares over its frames).
fn fitted_bias(s: &Session, apexes: &[Option<([f64; 2], [f64; 2])>]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (t, (a, d)) in s
        .truth
        .iter()
        .zip(apexes)
        .filter_map(|(t, a)| a.map(|a| (t, a)))
    {
        num += d[0] * (t.tip[0] - a[0]) + d[1] * (t.tip[1] - a[1]);
        den += d[0] * d[0] + d[1] * d[1];
    }
    num / den
}

/// The apex error's median over `s`'s frames with the edge bias `bias`.
fn apex_median_px(s: &Session, apexes: &[Option<([f64; 2], [f64; 2])>], bias: f64) -> f64 {
    let errors: Vec<f64> = s
        .truth
        .iter()
        .zip(apexes)
        .filter_map(|(t, a)| {
            a.map(|(a, d)| (a[0] + bias * d[0] - t.tip[0]).hypot(a[1] + bias * d[1] - t.tip[1]))
        })
        .collect();
    percentile(&errors, 50.0)
}

#[test]
fn apex_in_the_samples_convention_calibrated_on_the_other_session() {
    // The samples' truth counts pixels from the top-left pixel's corner, and its
    // outline lies inside the imaged edges (docs/tracker.md, Public samples). Written
    // with pixel_origin = "corner", the edge bias fitted on one session brings the
    // other session's apex median well under the 0.5 px target (docs/tracker.md): an
    // instrument calibration that transfers between two probes, not a fit to the
    // frames scored.
    let sessions = [sample("mixed"), sample("sequence")];
    let apexes = sessions.each_ref().map(corner_apexes);
    let bias = [0, 1].map(|k| fitted_bias(&sessions[k], &apexes[k]));
    let held_out = [0, 1].map(|k| apex_median_px(&sessions[k], &apexes[k], bias[1 - k]));
    let unbiased = [0, 1].map(|k| apex_median_px(&sessions[k], &apexes[k], 0.0));
    let why = format!(
        "edge bias fitted on mixed, sequence: {bias:?}; apex medians with the other's \
         bias {held_out:?}, with none {unbiased:?}"
    );
    // Measured 0.291 and 0.306 px: the same to 0.015 px on two different probes.
    assert!(bias.iter().all(|b| (0.27..=0.33).contains(b)), "{why}");
    assert!((bias[0] - bias[1]).abs() <= 0.03, "{why}");
    // Measured 0.124 (mixed) and 0.104 px (sequence); without the bias, corner-counted
    // apexes are 0.66 and 0.70 px off, as far as the default's centre-counted ones.
    assert!(held_out[0] <= 0.135, "{why}");
    assert!(held_out[1] <= 0.115, "{why}");
    assert!(unbiased.iter().all(|m| *m >= 0.6), "{why}");
    println!("{why}");
}

#[test]
fn forces_follow_the_model_and_the_truth() {
    let s = sample("sequence");
    let est = s.run(false);
    for (t, e) in s.truth.iter().zip(&est) {
        let angle = e.angle_deg.expect("detected");
        let model = s.config.probes[0].cantilever.unwrap().force_nn(angle);
        assert_eq!(e.force_nn, Some(model.value));
        assert!(!e.force_saturated);
        // The force error is the angle error times the local stiffness.
        let cantilever = s.config.probes[0].cantilever.unwrap();
        let per_deg = cantilever.force_nn(t.angle_deg + 0.5).value
            - cantilever.force_nn(t.angle_deg - 0.5).value;
        let allowed = per_deg.abs() * 0.12 + 1e-9;
        assert!(
            (model.value - t.force_nn).abs() <= allowed,
            "{}: {} vs {}",
            t.frame,
            model.value,
            t.force_nn
        );
    }
}

#[test]
fn the_reference_reads_zero_and_clicks_are_refined() {
    for name in ["mixed", "sequence"] {
        let s = sample(name);
        let cal = s.calibrate();
        let mut tracker = Tracker::new(&s.config.probes[0].tracker, cal.clone(), None);
        let e = tracker.track(&s.reference);
        let angle = e.angle_deg.expect("the reference is detected");
        assert!(angle.abs() < 0.005, "{name}: reference reads {angle}");
        let apex = e.apex_px.expect("apex");
        let ref_apex = cal.apex_px();
        assert!(
            (apex[0] - ref_apex[0]).hypot(apex[1] - ref_apex[1]) < 0.05,
            "{name}"
        );
        // Clicks alone are tenths of a degree off (docs/conventions.md); the refined
        // orientation moves away from them by about that much.
        let moved: f64 = Edge::ALL
            .iter()
            .map(|&edge| {
                let c = cal.edge(edge);
                (c.orientation_deg - c.clicked_orientation_deg).abs()
            })
            .fold(0.0, f64::max);
        assert!(moved > 0.05 && moved < 1.0, "{name}: {moved}");
    }
}

#[test]
fn result_csvs_for_nanoforce_score() {
    let out = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("tracker-results");
    std::fs::create_dir_all(&out).unwrap();
    for name in ["mixed", "sequence"] {
        let s = sample(name);
        let est = s.run(false);
        let csv = result_csv(&s.truth, &est);
        assert_eq!(csv.lines().count(), s.truth.len() + 1);
        std::fs::write(out.join(format!("{name}.csv")), csv).unwrap();
    }
}

#[test]
fn bad_calibration_input_is_named() {
    let s = sample("mixed");
    let clicks = s.config.probes[0].tracker.calibration.clone().unwrap();
    let cfg = &s.config.probes[0].tracker;
    let mut outside = clicks.clone();
    outside.points_mut("blue").unwrap()[1] = [700.0, 20.0];
    let err = Calibration::from_reference(&s.reference, &outside, cfg).unwrap_err();
    assert!(
        matches!(
            err,
            VisionError::ClickOutside {
                edge: Edge::Blue,
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string().contains("blue click [700.0, 20.0]"),
        "{err}"
    );
    // Clicks on the empty background: no edge there.
    let mut nowhere = clicks.clone();
    *nowhere.points_mut("green").unwrap() = vec![[560.0, 300.0], [590.0, 330.0], [610.0, 350.0]];
    let err = Calibration::from_reference(&s.reference, &nowhere, cfg).unwrap_err();
    assert!(
        matches!(
            err,
            VisionError::EdgeNotFound {
                edge: Edge::Green,
                ..
            }
        ),
        "{err}"
    );
    // Blue and green swapped: the faces do not enclose a bright pyramid.
    let mut swapped = clicks.clone();
    let blue = swapped.points("blue").unwrap().to_vec();
    let green = std::mem::replace(swapped.points_mut("green").unwrap(), blue);
    *swapped.points_mut("blue").unwrap() = green;
    let err = Calibration::from_reference(&s.reference, &swapped, cfg).unwrap_err();
    assert!(matches!(err, VisionError::Degenerate(_)), "{err}");
    // The same clicks on a blank image.
    let blank = image::GrayImage::from_pixel(640, 480, image::Luma([70]));
    let err = Calibration::from_reference(&blank, &clicks, cfg).unwrap_err();
    assert!(matches!(err, VisionError::EdgeNotFound { .. }), "{err}");
}

#[test]
fn overlays_draw_the_edges_in_their_colours() {
    let s = sample("mixed");
    let cal = s.calibrate();
    let mut tracker = Tracker::new(&s.config.probes[0].tracker, cal.clone(), None);
    let frame = s.frame("frame_00001.png");
    let est = tracker.track(&frame);
    let img = draw_overlay(&frame, &est);
    assert_eq!(img.dimensions(), frame.dimensions());
    for (edge, colour) in [
        (Edge::Red, [255, 40, 40]),
        (Edge::Blue, [60, 110, 255]),
        (Edge::Green, [40, 220, 60]),
    ] {
        let fit = est.edges[edge.index()].expect("all three edges in view");
        let mid = [
            0.5 * (fit.start_px[0] + fit.end_px[0]),
            0.5 * (fit.start_px[1] + fit.end_px[1]),
        ];
        let near = (-2..=2)
            .flat_map(|dy| (-2..=2).map(move |dx| (dx, dy)))
            .any(|(dx, dy)| {
                let (x, y) = ((mid[0] as i32 + dx) as u32, (mid[1] as i32 + dy) as u32);
                *img.get_pixel(x, y) == Rgb(colour)
            });
        assert!(near, "{edge} not drawn at {mid:?}");
    }
    let cal_img = draw_calibration(&s.reference, &cal);
    let apex = cal.apex_px();
    let ring = (-7..=7).any(|d| {
        *cal_img.get_pixel((apex[0] as i32 + d) as u32, (apex[1] as i32 - 6) as u32)
            == Rgb([255, 230, 0])
    });
    assert!(ring, "apex marker");
}

/// `tracker.scale_range` on the AFM pyramid: a range around the sample's own scales
/// keeps every detection; a range above them refuses every frame whose scale the beam
/// edge measures as a scale mismatch, and leaves those showing only the faces (which
/// leave the scale free: their estimate reports none) to the other checks.
#[test]
fn a_stated_scale_range_keeps_the_probe_and_refuses_other_sizes() {
    let s = sample("sequence");
    let cfg = s.config.probes[0].tracker.clone();
    let found = s.run_with(&cfg, false);
    let scales: Vec<f64> = found.iter().filter_map(|e| e.scale).collect();
    assert!(!scales.is_empty());
    let lo = scales.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = scales.iter().copied().fold(0.0, f64::max);
    let around = TrackerConfig {
        scale_range: Some(ScaleRange::new(0.95 * lo, 1.05 * hi)),
        ..cfg.clone()
    };
    let kept = s.run_with(&around, false);
    let detected = |v: &[Estimate]| v.iter().filter(|e| e.detected).count();
    assert_eq!(detected(&kept), detected(&found));
    let above = TrackerConfig {
        scale_range: Some(ScaleRange::new(1.3 * hi, 2.0 * hi)),
        ..cfg
    };
    let mut refused = 0;
    for (e, was) in s.run_with(&above, false).iter().zip(&found) {
        if was.scale.is_some() {
            assert_eq!(e.miss, Some(Miss::ScaleMismatch), "{e:?}");
            refused += 1;
        } else {
            assert_eq!(e.detected, was.detected, "{e:?}");
        }
    }
    assert!(refused >= found.len() / 2, "{refused} of {}", found.len());
}
