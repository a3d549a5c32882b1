//! The tracker on frames rendered over crops of real SEM frames (`tests/data/real-sem`):
//! probes brighter and darker than their background, low contrast, bright textured
//! backgrounds, charging, scan-line jitter, noise up to sigma 48 and a second needle in
//! view, one or two conditions per session (`nanoforce::scene::real_suite`).
//! Run with `cargo test --release --test tracker_realbg`.
mod tracker_support;

use nanoforce::scene;
use nanoforce::vision::{Calibration, Edge, VisionError};
use tracker_support::{rendered, score, table};

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
    // (scene::real_suite). Held-out seed 71; developed on 5 (SUITE_SEED=n for others,
    // SUITE_TABLE=1 for every frame).
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
    assert_eq!(t.len(), 600);
    // Session 10 (strong noise, sigma 30-48, over a bright texture) is the hardest:
    // seed 71 detects 32 of its 44 probes (frames whose faces Canny breaks up), seed 5
    // 43 of 44. The rest: 528 of 530 (seed 71), 513 of 518 (seed 5).
    let others: Vec<usize> = (0..t.len()).filter(|&i| i / 50 != 10).collect();
    let pick = |idx: &[usize]| -> (Vec<_>, Vec<_>) {
        (
            idx.iter().map(|&i| t[i].clone()).collect(),
            idx.iter().map(|&i| e[i]).collect(),
        )
    };
    let (to, eo) = pick(&others);
    let rest = score(&to, &eo);
    println!("without session 10: {rest:?}");
    // Measured on seed 71: 97.6 % (560 of 574), the rest 99.6 %; 1 blank frame with a
    // needle in view detected (session 7; seed 5: session 5, confidence 0.81); angle
    // error median 0.0312, p95 0.120, max 0.267 deg; apex median 0.255 px.
    assert!(sc.detect_rate >= 0.97, "{why}");
    assert!(rest.detect_rate >= 0.995, "{rest:?}");
    assert!(sc.false_detections <= 1, "{why}");
    assert!(sc.angle_err_median_deg <= 0.035, "{why}");
    assert!(sc.angle_err_p95_deg <= 0.13, "{why}");
    assert!(sc.angle_err_max_deg <= 0.3, "{why}");
    assert!(sc.tip_err_median_px <= 0.3, "{why}");
    // Frames with noise sigma up to 30: the error stays within 0.3 deg.
    let quiet: Vec<usize> = (0..t.len())
        .filter(|&i| sessions[i / 50].frames[i % 50].look.noise_sigma <= 30.0)
        .collect();
    let (tq, eq) = pick(&quiet);
    let sq = score(&tq, &eq);
    println!("noise <= 30: {sq:?}");
    assert!(sq.angle_err_max_deg <= 0.3, "{sq:?}");
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
        let (_, truth) = scene::render(&session.reference);
        let truth = truth.edges.expect("the reference shows the probe");
        let (_, cal) = rendered::calibrate_over(&session, &crops);
        for (edge, seg) in Edge::ALL
            .into_iter()
            .zip([truth.red, truth.blue, truth.green])
        {
            let e = cal.edge(edge);
            assert_eq!(e.polarity, contrast.signum(), "{contrast}: {edge}");
            assert_eq!(e.contrast.signum(), contrast.signum(), "{contrast}: {edge}");
            let d = [seg.to[0] - seg.from[0], seg.to[1] - seg.from[1]];
            let mut want = -d[1].atan2(d[0]).to_degrees();
            while want > 90.0 {
                want -= 180.0;
            }
            while want <= -90.0 {
                want += 180.0;
            }
            let err = (e.orientation_deg - want + 90.0).rem_euclid(180.0) - 90.0;
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
