//! `Estimate::angle_sigma_deg` is a calibrated standard error: over rendered suites with
//! exact truth, |error| / sigma has the median a Gaussian's has (0.67, accepted in
//! 0.5-0.9) and almost no detection lies beyond 4 sigma.
//!
//! The suites are `scene::suite`'s, plus the same frames made harder one condition at a
//! time (noise up to 48 grey levels, scan-line jitter on a fifth of the rows, blur
//! 1.6 px, the probe 30-45 levels above its background). The constants of the sigma
//! model (`src/vision/sigma.rs`) were fitted on seeds 1-13 and 31; seed 41 is held out
//! here. Run with `cargo test --release --test tracker_sigma`; `SIGMA_SEED=n` for
//! another seed, `SIGMA_DUMP=path.csv` for every detection's numbers.
mod tracker_support;

use nanoforce::scene::{self, Session};
use nanoforce::vision::Estimate;
use tracker_support::{rendered, Truth};

/// The held-out seed.
const HELD_OUT_SEED: u64 = 41;

/// The condition a frame of the stressed suite is made harder by, besides its style.
const STRESSES: [&str; 4] = ["noise", "jitter", "blur", "contrast"];

/// `scene::suite(seed, 12, 50)` with every frame made harder by one of [`STRESSES`]
/// in turn.
fn stressed_suite(seed: u64) -> Vec<Session> {
    let mut sessions = scene::suite(seed, 12, 50);
    for (i, s) in sessions.iter_mut().enumerate() {
        for (k, f) in s.frames.iter_mut().enumerate() {
            let look = &mut f.look;
            let stress = STRESSES[(k + i) % STRESSES.len()];
            look.style_name = stress;
            match stress {
                "noise" => look.noise_sigma = (1.6 * look.noise_sigma).min(48.0),
                "jitter" => look.jitter_fraction = 0.2,
                "blur" => look.blur_sigma_px = 1.6,
                _ => {
                    let above = 30.0 + 15.0 * ((k % 3) as f64 / 2.0);
                    look.probe = look.background + above;
                    look.substrate = look.substrate.map(|l| l.min(look.background + 20.0));
                }
            }
        }
    }
    sessions
}

/// Signed error / sigma of every frame with the probe, detected.
fn z_scores(t: &[Truth], e: &[Estimate]) -> Vec<f64> {
    t.iter()
        .zip(e)
        .filter(|(t, e)| t.detected && e.detected)
        .map(|(t, e)| {
            (e.angle_deg.unwrap_or(f64::NAN) - t.angle_deg) / e.angle_sigma_deg.unwrap_or(0.0)
        })
        .collect()
}

/// Median of |z| and the share of |z| beyond 4.
fn calibration(z: &[f64]) -> (f64, f64) {
    let mut a: Vec<f64> = z.iter().map(|z| z.abs()).collect();
    a.sort_by(f64::total_cmp);
    let median = if a.is_empty() {
        f64::NAN
    } else {
        a[a.len() / 2]
    };
    let beyond =
        a.iter().filter(|&&z| z.is_nan() || z > 4.0).count() as f64 / a.len().max(1) as f64;
    (median, beyond)
}

fn dump(path: &str, sets: &[(&str, &[Truth], &[Estimate])]) {
    let mut csv = String::from("suite,style,magnification,err_deg,sigma_deg,confidence\n");
    for (name, t, e) in sets {
        for (t, e) in t
            .iter()
            .zip(e.iter())
            .filter(|(t, e)| t.detected && e.detected)
        {
            csv += &format!(
                "{name},{},{},{},{},{}\n",
                t.style,
                t.magnification,
                e.angle_deg.unwrap_or(f64::NAN) - t.angle_deg,
                e.angle_sigma_deg.unwrap_or(f64::NAN),
                e.confidence
            );
        }
    }
    std::fs::write(path, csv).unwrap_or_else(|err| panic!("SIGMA_DUMP={path}: {err}"));
}

#[test]
fn angle_sigma_is_a_calibrated_standard_error() {
    let seed = std::env::var("SIGMA_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(HELD_OUT_SEED);
    let (t0, e0) = rendered::run_all(&scene::suite(seed, 12, 50), false, |_| ());
    let (t1, e1) = rendered::run_all(&stressed_suite(seed), false, |_| ());
    if let Ok(path) = std::env::var("SIGMA_DUMP") {
        dump(&path, &[("suite", &t0, &e0), ("stressed", &t1, &e1)]);
    }
    let mut all = Vec::new();
    for (name, t, e) in [("suite", &t0, &e0), ("stressed", &t1, &e1)] {
        let z = z_scores(t, e);
        let (median, beyond) = calibration(&z);
        println!(
            "{name}: {} detections, median |error|/sigma {median:.3}, beyond 4 sigma {:.2} %",
            z.len(),
            100.0 * beyond
        );
        all.extend(z);
    }
    let (median, beyond) = calibration(&all);
    println!(
        "both: {} detections, median {median:.3}, beyond 4 sigma {:.2} %",
        all.len(),
        100.0 * beyond
    );
    assert!(all.len() >= 1000, "only {} detections", all.len());
    assert!(
        (0.5..=0.9).contains(&median),
        "median |error|/sigma {median}"
    );
    assert!(beyond <= 0.005, "{:.2} % beyond 4 sigma", 100.0 * beyond);
}
