//! The tracker on frames rendered over crops of real SEM frames (`tests/data/real-sem`):
//! probes brighter and darker than their background, low contrast, bright textured
//! backgrounds, charging, scan-line jitter, noise up to sigma 48 and a second needle in
//! view, one or two conditions per session (`nanoforce::scene::real_suite`).
//! Run with `cargo test --release --test tracker_realbg`.
mod tracker_support;

use nanoforce::scene;
use nanoforce::vision::{Calibration, Edge, VisionError};
use tracker_support::{percentile, rendered, score, table};

/// The suite seed from `SUITE_SEED`, else `default`.
fn suite_seed(default: u64) -> u64 {
    std::env::var("SUITE_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

#[test]
fn suite_of_600_frames_over_real_backgrounds() {
    // 12 sessions x 50 frames over the 12 crops, each session one or two conditions
    // (scene::real_suite). Held-out seed 71; developed on 5 and 13 (SUITE_SEED=n for
    // others, SUITE_TABLE=1 for every frame, SUITE_DUMP=dir for the missed frames).
    let crops = rendered::real_crops();
    assert_eq!(crops.len(), 12);
    let seed = suite_seed(71);
    let sessions = scene::real_suite(seed, 12, 50, crops.len());
    let (t, e) = rendered::run_all_over(&sessions, &crops);
    let sc = score(&t, &e);
    let why = format!("{sc:?}\n{}", table(&t, &e));
    println!("all: {sc:?}");
    for (i, (ts, es)) in t.chunks(50).zip(e.chunks(50)).enumerate() {
        println!("session {i}: {:?}", score(ts, es));
    }
    if std::env::var("SUITE_TABLE").is_ok() {
        println!("{}", table(&t, &e));
    }
    // Each missed probe frame is fitted from its true pose too: detected there, the
    // search missed it; refused there, the verification refuses the frame itself.
    let from_truth = rendered::misses_from_truth(&sessions, &crops, &t, &e);
    for (i, (ti, ei)) in t.iter().zip(&e).enumerate() {
        if ti.detected != ei.detected {
            let look = &sessions[i / 50].frames[i % 50].look;
            let real = look.real.expect("a real background");
            let at_truth =
                from_truth
                    .iter()
                    .find(|(j, _)| *j == i)
                    .map_or(String::new(), |(_, a)| match a.miss {
                        Some(m) => format!("; from the true pose too: {}", m.name()),
                        None => "; the true pose verifies".into(),
                    });
            println!(
                "s{:02} f{:02} in view {} mag {:5.0}: contrast {:+5.1} noise {:4.1} texture {:4.1} \
                 level {:5.1} gain {:.2} jitter {:.2} needle {} -> conf {:.2} miss {}{at_truth}",
                i / 50,
                i % 50,
                ti.detected,
                ti.magnification,
                look.probe - look.background,
                look.noise_sigma,
                real.texture_sigma,
                real.level,
                look.charging_gain,
                look.jitter_fraction,
                look.needle.is_some(),
                ei.confidence,
                ei.miss.map_or("none", |m| m.name())
            );
        }
    }
    let by_search = from_truth.iter().filter(|(_, a)| a.detected).count();
    println!(
        "missed probe frames: {} ({by_search} the search's: the true pose verifies)",
        from_truth.len()
    );
    if let Ok(dir) = std::env::var("SUITE_DUMP") {
        // The frames missed or falsely detected, as PNGs named by session and frame.
        std::fs::create_dir_all(&dir).unwrap_or_else(|err| panic!("SUITE_DUMP={dir}: {err}"));
        let mut frame = image::GrayImage::new(1, 1);
        for (i, (ti, ei)) in t.iter().zip(&e).enumerate() {
            if ti.detected != ei.detected {
                let spec = &sessions[i / 50].frames[i % 50];
                scene::render_over_into(spec, &crops, &mut frame);
                let path = format!("{dir}/s{:02}_f{:02}.png", i / 50, i % 50);
                frame
                    .save(&path)
                    .unwrap_or_else(|err| panic!("{path}: {err}"));
            }
        }
    }
    assert_eq!(t.len(), 600);
    let z: Vec<f64> = t
        .iter()
        .zip(&e)
        .filter(|(t, e)| t.detected && e.detected)
        .map(|(t, e)| {
            ((e.angle_deg.unwrap_or(f64::NAN) - t.angle_deg) / e.angle_sigma_deg.unwrap_or(0.0))
                .abs()
        })
        .collect();
    let mut zs = z.clone();
    zs.sort_by(f64::total_cmp);
    let beyond = z.iter().filter(|&&z| z.is_nan() || z > 4.0).count();
    println!(
        "|error|/sigma: median {:.3}, beyond 4 sigma {beyond} of {}",
        zs[zs.len() / 2],
        z.len()
    );
    for (i, (ti, ei)) in t.iter().zip(&e).enumerate() {
        if let (true, Some(a), Some(sg)) = (ti.detected, ei.angle_deg, ei.angle_sigma_deg) {
            if ((a - ti.angle_deg) / sg).abs() > 4.0 {
                let look = &sessions[i / 50].frames[i % 50].look;
                println!(
                    "  beyond 4: s{:02} f{:02} err {:+.3} sigma {:.4} noise {:.1} contrast {:+.1} texture {:.1} jitter {:.2}",
                    i / 50, i % 50, a - ti.angle_deg, sg, look.noise_sigma,
                    look.probe - look.background,
                    look.real.map_or(0.0, |r| r.texture_sigma), look.jitter_fraction
                );
            }
        }
    }
    let pick = |idx: &[usize]| -> (Vec<_>, Vec<_>) {
        (
            idx.iter().map(|&i| t[i].clone()).collect(),
            idx.iter().map(|&i| e[i]).collect(),
        )
    };
    // Measured on seed 71: 573 of 574 detected (99.83 %; one at 6971x under noise 44
    // that the search leaves incomplete); no false detection (blank frames with a
    // needle in view included); angle error median 0.0315, p95 0.121 deg (noise 30-48
    // frames included), apex median 0.26 px.
    assert!(sc.detect_rate >= 0.998, "{why}");
    assert_eq!(sc.false_detections, 0, "{why}");
    assert!(sc.angle_err_median_deg <= 0.033, "{why}");
    assert!(sc.angle_err_p95_deg <= 0.13, "{why}");
    assert!(sc.tip_err_median_px <= 0.3, "{why}");
    // The reported sigma is honest here too (0.69; 1 of 573 beyond 4 sigma).
    let median_z = zs[zs.len() / 2];
    assert!(
        (0.5..=0.9).contains(&median_z),
        "median |error|/sigma {median_z}"
    );
    assert!(
        beyond as f64 <= 0.005 * z.len() as f64,
        "{beyond} of {} beyond 4 sigma",
        z.len()
    );
    // Frames with noise sigma up to 30: the error stays within 0.3 deg (0.225 measured);
    // beyond, the reported sigma covers it (0.327 deg at noise 30-48,
    // within 4 of its reported sigmas).
    let quiet: Vec<usize> = (0..t.len())
        .filter(|&i| sessions[i / 50].frames[i % 50].look.noise_sigma <= 30.0)
        .collect();
    let (tq, eq) = pick(&quiet);
    let sq = score(&tq, &eq);
    println!("noise <= 30: {sq:?}");
    assert!(sq.angle_err_max_deg <= 0.3, "{sq:?}");
}

#[test]
fn every_probe_of_the_suite_is_visible() {
    // The visibility rule of docs/renderer.md: the probe's contrast (after charging)
    // is at least the noise and the background's texture together, per pixel
    // (|contrast| >= sqrt(noise^2 + texture^2)); a person sees such a probe plainly
    // over its faces of tens of pixels. A probe 10 levels from its background under
    // noise 48 (0.2) is what the suite never draws.
    for seed in [71, 5, 13] {
        let mut lowest = f64::INFINITY;
        for session in scene::real_suite(seed, 12, 50, 12) {
            for spec in session.frames.iter().filter(|s| !s.blank) {
                let look = &spec.look;
                let texture = look.real.expect("a real background").texture_sigma;
                let contrast = (look.probe - look.background).abs() * look.charging_gain;
                lowest = lowest.min(contrast / look.noise_sigma.hypot(texture));
            }
        }
        println!("seed {seed}: lowest contrast / (noise and texture) {lowest:.2}");
        assert!(lowest >= 1.0, "seed {seed}: {lowest}");
    }
}

/// The noisy sessions (noise 30-48: alone, with scan-line jitter, over a bright textured
/// ground; sessions 4, 8 and 10 of `scene::real_suite`) of three seeds that no
/// threshold was set on, 428 probe frames. A missed frame there is searched again at
/// three coarser binnings in turn (`vision::tracker`, `COARSE_RETRIES`): measured 409
/// detected, 406 with the twice-as-coarse search alone; none of the blank frames.
#[test]
fn noisy_sessions_are_searched_again_coarser() {
    let crops = rendered::real_crops();
    let (mut probes, mut found, mut false_detections) = (0, 0, 0);
    for seed in [101, 102, 103] {
        let sessions = scene::real_suite(seed, 12, 50, crops.len());
        let noisy: Vec<_> = [4, 8, 10].map(|i| sessions[i].clone()).into();
        let (t, e) = rendered::run_all_over(&noisy, &crops);
        for (t, e) in t.iter().zip(&e) {
            probes += usize::from(t.detected);
            found += usize::from(t.detected && e.detected);
            false_detections += usize::from(!t.detected && e.detected);
        }
    }
    println!("noisy sessions: {found} of {probes} detected, {false_detections} false");
    assert_eq!(probes, 428);
    assert!(found >= 408, "{found} of {probes}");
    assert_eq!(false_detections, 0);
}

/// A session of `n` frames of one setup over a bright, finely textured background, the
/// probe `contrast` grey levels from it (negative: darker), the reference at noise 3.
fn bright_background_session(seed: u64, contrast: f64, n: usize) -> scene::Session {
    let mut session = scene::real_suite(seed, 1, n, 12).remove(0);
    for spec in std::iter::once(&mut session.reference).chain(&mut session.frames) {
        let look = &mut spec.look;
        let real = look.real.as_mut().expect("a real background");
        real.level = 180.0;
        real.texture_sigma = 0.15 * contrast.abs();
        look.outline = 0.0;
        look.probe = 180.0 + contrast;
        look.probe_ramp = 0.0;
        look.needle = None;
        look.jitter_fraction = 0.0;
        look.charging_gain = 1.0;
    }
    session.reference.look.noise_sigma = 3.0;
    session
}

#[test]
fn calibrates_either_polarity_at_low_contrast() {
    let crops = rendered::real_crops();
    // Faces 5 to 16 grey levels above or below a bright background (180).
    for (k, contrast) in [5.0, 8.0, 16.0, -5.0, -8.0, -16.0].into_iter().enumerate() {
        let session = bright_background_session(900 + k as u64, contrast, 0);
        let (cal, errors) = reference_read(&session, &crops);
        for (edge, err) in Edge::ALL.into_iter().zip(errors) {
            let e = cal.edge(edge);
            assert_eq!(e.polarity, contrast.signum(), "{contrast}: {edge}");
            assert_eq!(e.contrast.signum(), contrast.signum(), "{contrast}: {edge}");
            // At 5 levels over noise 3 a face is measured to a few tenths of a degree,
            // and calibrate says so: the error lies within its reported sigma's reach.
            let sigma = e.orientation_sigma_deg;
            println!("{contrast:+}: {edge} err {err:+.3} sigma {sigma:.3} deg");
            assert!(
                err.abs() < 0.03 + 4.0 * sigma,
                "{contrast}: {edge} {err:.3} deg, sigma {sigma:.3}"
            );
        }
    }
}

/// `session`'s calibration on its reference rendered over `crops`, and how far off
/// each edge's orientation it read is (red, blue, green), degrees.
fn reference_read(session: &scene::Session, crops: &[image::GrayImage]) -> (Calibration, [f64; 3]) {
    let (_, truth) = scene::render(&session.reference);
    let truth = truth.edges.expect("the reference shows the probe");
    let (_, cal) = rendered::calibrate_over(session, crops);
    let errors = [
        (Edge::Red, truth.red),
        (Edge::Blue, truth.blue),
        (Edge::Green, truth.green),
    ]
    .map(|(edge, seg)| {
        let d = [seg.to[0] - seg.from[0], seg.to[1] - seg.from[1]];
        let want = -d[1].atan2(d[0]).to_degrees();
        (cal.edge(edge).orientation_deg - want + 90.0).rem_euclid(180.0) - 90.0
    });
    (cal, errors)
}

/// The crops, seed and sessions the measurements for docs/tracker.md run on: the
/// suite of `SUITE_SEED`, held-out seed 71 by default.
fn measured_suite() -> (Vec<image::GrayImage>, u64, Vec<scene::Session>) {
    let crops = rendered::real_crops();
    let seed = suite_seed(71);
    let sessions = scene::real_suite(seed, 12, 50, crops.len());
    (crops, seed, sessions)
}

#[test]
#[ignore = "a measurement for docs/tracker.md: cargo test --release --test tracker_realbg -- --ignored --nocapture"]
fn the_reference_sets_each_session_s_bias() {
    // Per session: how far off the reference's edges were read, and the mean error of
    // the session's detections (all tracked on that reading). A reference edge read
    // turned moves every frame's angle the other way. Then the suite's median and p95
    // with each session's mean error taken out: the most any per-session correction
    // of the reference's reading could give.
    let (crops, seed, sessions) = measured_suite();
    let (truths, estimates) = rendered::run_all_over(&sessions, &crops);
    let (mut read, mut bias) = (Vec::new(), Vec::new());
    let (mut as_tracked, mut unbiased) = (Vec::new(), Vec::new());
    let per_session = truths.chunks(50).zip(estimates.chunks(50));
    for (i, (session, (ts, es))) in sessions.iter().zip(per_session).enumerate() {
        let (_, errors) = reference_read(session, &crops);
        let frame_errors: Vec<f64> = ts
            .iter()
            .zip(es)
            .filter(|(t, e)| t.detected && e.detected)
            .map(|(t, e)| e.angle_deg.unwrap() - t.angle_deg)
            .collect();
        let mean = frame_errors.iter().sum::<f64>() / frame_errors.len() as f64;
        as_tracked.extend(frame_errors.iter().map(|e| e.abs()));
        unbiased.extend(frame_errors.iter().map(|e| (e - mean).abs()));
        let edges = errors.iter().sum::<f64>() / 3.0;
        println!(
            "session {i:2}: reference edges read {:+.3} {:+.3} {:+.3} deg off (mean {edges:+.4}); \
             its {} detections' mean error {mean:+.4} deg",
            errors[0],
            errors[1],
            errors[2],
            frame_errors.len()
        );
        read.push(edges);
        bias.push(mean);
    }
    let n = read.len() as f64;
    let (mr, mb) = (read.iter().sum::<f64>() / n, bias.iter().sum::<f64>() / n);
    let sxy: f64 = read
        .iter()
        .zip(&bias)
        .map(|(r, b)| (r - mr) * (b - mb))
        .sum();
    let sxx: f64 = read.iter().map(|r| (r - mr).powi(2)).sum();
    let syy: f64 = bias.iter().map(|b| (b - mb).powi(2)).sum();
    println!(
        "seed {seed}: correlation of a session's mean error with its reference's mean edge \
         error {:.2}, slope {:.2}",
        sxy / (sxx * syy).sqrt(),
        sxy / sxx
    );
    let quantiles = |v: &[f64]| (percentile(v, 50.0), percentile(v, 95.0));
    let ((m0, p0), (m1, p1)) = (quantiles(&as_tracked), quantiles(&unbiased));
    println!(
        "seed {seed}: angle error median {m0:.4}, p95 {p0:.4} deg; with each session's mean \
         error taken out, median {m1:.4}, p95 {p1:.4} deg"
    );
}

#[test]
fn calibration_names_the_edge_without_contrast() {
    let crops = rendered::real_crops();
    let session = bright_background_session(910, 0.0, 0);
    let cfg = rendered::tracker_config(&session);
    let mut reference = image::GrayImage::new(1, 1);
    scene::render_over_into(&session.reference, &crops, &mut reference);
    let err = Calibration::from_reference(&reference, cfg.calibration.as_ref().unwrap(), &cfg)
        .unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(err, VisionError::EdgeNotFound { .. }) && text.contains("no contrast"),
        "{text}"
    );
}

#[test]
#[ignore = "a measurement for docs/tracker.md: cargo test --release --test tracker_realbg -- --ignored --nocapture"]
fn the_tracker_noise_sets_the_p95() {
    // The suite's angle p95 against the tracker's own noise: each frame with the probe is
    // drawn again six times with other seeds (the same conditions: probe, pose,
    // background crop, contrast, noise level; new noise, shading and jitter) and tracked
    // from scratch. Per frame, the estimates' spread is the estimator's noise there and
    // their mean error its bias. The p95 an estimator with that noise and no bias would
    // reach is the x where the frames' mean P(|N(0, spread)| > x) is 5 % (the median's:
    // 50 %).
    let (crops, seed, sessions) = measured_suite();
    // (noise sigma of the frame, spread, bias), degrees.
    let mut frames: Vec<(f64, f64, f64)> = Vec::new();
    for s in &sessions {
        let mut tracker = rendered::tracker_over(s, &crops);
        let mut frame = image::GrayImage::new(1, 1);
        for spec in s.frames.iter().filter(|f| !f.blank) {
            let mut errors = Vec::new();
            for draw in 1..=6u64 {
                let mut again = *spec;
                again.seed = spec.seed.wrapping_mul(31).wrapping_add(draw);
                let truth = scene::render_over_into(&again, &crops, &mut frame);
                if let Some(a) = tracker.track(&frame).angle_deg {
                    errors.push(a - truth.angle_deg);
                }
            }
            if errors.len() < 3 {
                continue;
            }
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let var =
                errors.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / (errors.len() - 1) as f64;
            frames.push((spec.look.noise_sigma, var.sqrt(), mean));
        }
    }
    // The x at which the frames' mean chance of an error beyond x is `share`.
    let quantile = |share: f64, bias: bool, of: &dyn Fn(f64) -> bool| -> f64 {
        let chosen: Vec<_> = frames.iter().filter(|f| of(f.0)).collect();
        let beyond = |x: f64| {
            chosen
                .iter()
                .map(|&&(_, s, b)| {
                    let b = if bias { b } else { 0.0 };
                    let z = std::f64::consts::SQRT_2 * s.max(1e-9);
                    0.5 * (erfc((x - b) / z) + erfc((x + b) / z))
                })
                .sum::<f64>()
                / chosen.len() as f64
        };
        let (mut lo, mut hi) = (0.0, 5.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if beyond(mid) > share {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    };
    let all = |_: f64| true;
    let quiet = |n: f64| n <= 30.0;
    for (name, share) in [("median", 0.5), ("p95", 0.05)] {
        println!(
            "seed {seed}: {} frames with the probe, each drawn 6 times; the {name} of an \
             estimator with the tracker's noise and no bias: {:.4} deg (noise <= 30: \
             {:.4}); with its bias too: {:.4} deg (noise <= 30: {:.4})",
            frames.len(),
            quantile(share, false, &all),
            quantile(share, false, &quiet),
            quantile(share, true, &all),
            quantile(share, true, &quiet),
        );
    }
}

/// The complementary error function (Numerical Recipes' erfcc, |error| < 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[test]
fn calibration_reads_each_face_to_its_base() {
    // Every reference of five suites (60, with lines of the background crossing some
    // faces near their bases): each face's calibrated length within verification's
    // slack for where a face ends (a tenth) of its true length.
    let crops = rendered::real_crops();
    let mut worst: (f64, String) = (0.0, String::new());
    for seed in [71, 5, 7, 13, 21] {
        for (i, session) in scene::real_suite(seed, 12, 50, crops.len())
            .iter()
            .enumerate()
        {
            let mut reference = image::GrayImage::new(1, 1);
            let truth = scene::render_over_into(&session.reference, &crops, &mut reference);
            let edges = truth.edges.expect("the reference shows the probe");
            let (_, cal) = rendered::calibrate_over(session, &crops);
            let apex = [truth.tip_x, truth.tip_y];
            let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
            for (edge, base) in [(Edge::Blue, edges.blue.from), (Edge::Green, edges.green.to)] {
                let far = cal.edge(edge).segment_px[1];
                let off = dist(far, apex) / dist(base, apex) - 1.0;
                if off.abs() > worst.0 {
                    worst = (
                        off.abs(),
                        format!("seed {seed} session {i} {edge}: {off:+.3}"),
                    );
                }
            }
        }
    }
    println!("largest: {}", worst.1);
    assert!(worst.0 < 0.1, "{}", worst.1);
}
