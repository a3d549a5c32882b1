use super::*;
use gauss::normal_cdf;
use image::Luma;

/// A blurred bright half-plane `n . p > rho` with noise-free grey levels.
fn half_plane(normal_angle: f64, rho: f64, blur: f64) -> GrayImage {
    let n = [normal_angle.cos(), normal_angle.sin()];
    GrayImage::from_fn(200, 150, |x, y| {
        let d = n[0] * x as f64 + n[1] * y as f64 - rho;
        Luma([(60.0 + 150.0 * normal_cdf(d / blur)).round() as u8])
    })
}

/// A band along `line` from x = 20 to x = 180 (feet of the points at height `y`), no
/// bend and no neighbouring faces.
fn straight_band(line: Line, y: f64) -> Band {
    Band {
        start: line.foot([20.0, y]),
        end: line.foot([180.0, y]),
        line,
        bend_from: None,
        bend0: 0.0,
        bend_sigma: f64::INFINITY,
        partner: None,
        base: None,
    }
}

#[test]
fn recovers_a_tilted_edge_to_a_hundredth_of_a_pixel() {
    let angle = 100f64.to_radians();
    let img = half_plane(angle, 60.0, 1.2);
    // Start 0.8 deg and 0.7 px off.
    let start = 100.8f64.to_radians();
    let n0 = [start.cos(), start.sin()];
    let line = Line {
        normal: n0,
        rho: 60.7,
    };
    let band = straight_band(line, 70.0);
    let mut r = Refiner::default();
    let fit = r
        .fit(
            &img,
            &[None, Some(band), None],
            Turns::Free,
            1.0,
            None,
            false,
        )
        .unwrap();
    let e = fit.edges[1].unwrap();
    let got = e.line.normal[1].atan2(e.line.normal[0]);
    assert!(
        (got - angle).abs().to_degrees() < 0.01,
        "{}",
        got.to_degrees()
    );
    let truth = Line {
        normal: [angle.cos(), angle.sin()],
        rho: 60.0,
    };
    let p = e.line.foot([100.0, 60.0]);
    assert!(truth.depth(p).abs() < 0.02, "{}", truth.depth(p));
    assert!((e.contrast - 150.0).abs() < 2.0 && (fit.blur - 1.2).abs() < 0.1);
}

/// A bright strip between two edges, each turned by its own angle (radians) from
/// horizontal, noise-free: the top edge at y = 50 and the bottom one at y = 110
/// (at x = 100).
fn strip(top: f64, bottom: f64, blur: f64) -> GrayImage {
    GrayImage::from_fn(200, 160, |x, y| {
        let (x, y) = (x as f64 - 100.0, y as f64);
        let below_top = y - 50.0 - x * top.tan();
        let above_bottom = 110.0 + x * bottom.tan() - y;
        let inside = normal_cdf(below_top / blur) + normal_cdf(above_bottom / blur) - 1.0;
        Luma([(60.0 + 150.0 * inside).round() as u8])
    })
}

fn strip_bands() -> PerEdge<Option<Band>> {
    let band = |rho: f64, normal: [f64; 2]| Some(straight_band(Line { normal, rho }, rho.abs()));
    // Inward normals: down from the top edge, up from the bottom one.
    [None, band(50.0, [0.0, 1.0]), band(-110.0, [0.0, -1.0])]
}

/// The strip of [`strip`] (its edges level, blur 1) with smooth blobs beside it
/// (Gaussians of `radius` px, +-`amplitude` grey levels, 400 of them, which the
/// strip covers), and white noise of sigma 3; `seed` draws both.
fn strip_over_blobs(seed: u64, radius: f64, amplitude: f64) -> GrayImage {
    // xorshift64: a test's own stream of uniform draws in [0, 1).
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (w, h) = (200usize, 160usize);
    let mut texture = vec![0.0f64; w * h];
    let reach = (3.0 * radius).ceil() as i64;
    for _ in 0..400 {
        let (bx, by) = (w as f64 * uniform(), h as f64 * uniform());
        let a = if uniform() < 0.5 {
            -amplitude
        } else {
            amplitude
        };
        let (cx, cy) = (bx as i64, by as i64);
        for y in (cy - reach).max(0)..(cy + reach + 1).min(h as i64) {
            for x in (cx - reach).max(0)..(cx + reach + 1).min(w as i64) {
                let d2 = (x as f64 - bx).powi(2) + (y as f64 - by).powi(2);
                texture[y as usize * w + x as usize] += a * (-d2 / (2.0 * radius * radius)).exp();
            }
        }
    }
    let clean = strip(0.0, 0.0, 1.0);
    GrayImage::from_fn(w as u32, h as u32, |x, y| {
        let py = y as f64;
        let inside = normal_cdf(py - 50.0) + normal_cdf(110.0 - py) - 1.0;
        // Box-Muller.
        let (u1, u2) = (uniform().max(1e-12), uniform());
        let noise = 3.0 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
        let v = clean.get_pixel(x, y).0[0] as f64
            + (1.0 - inside) * texture[y as usize * w + x as usize]
            + noise;
        Luma([v.round().clamp(0.0, 255.0) as u8])
    })
}

/// Over `draws` images of [`strip_over_blobs`], each edge's turn fitted freely (its
/// truth is 0): the RMS error and the RMS of the two reported standard errors,
/// radians.
fn free_fit_errors(draws: u64, radius: f64) -> (f64, f64, f64) {
    let (mut error, mut formula, mut robust, mut n) = (0.0, 0.0, 0.0, 0.0);
    for seed in 1..=draws {
        let img = strip_over_blobs(seed, radius, 12.0);
        let fit = Refiner::default()
            .fit(&img, &strip_bands(), Turns::Free, 1.0, None, false)
            .unwrap();
        for r in fit.edges.iter().flatten() {
            error += r.turn * r.turn;
            formula += r.turn_sigma * r.turn_sigma;
            robust += r.turn_sigma_robust * r.turn_sigma_robust;
            n += 1.0;
        }
    }
    (
        (error / n).sqrt(),
        (formula / n).sqrt(),
        (robust / n).sqrt(),
    )
}

#[test]
fn a_free_fits_robust_sigma_covers_a_background_correlated_along_its_edges() {
    // Blobs of 3 px beside the edges leave residuals correlated along them over
    // several pixels, which the formula counts as independent: it gives about half
    // the error (0.46-0.60 over five sets of 30 draws), the stretches' spread
    // 0.89-1.23 of it. Blobs of half a pixel are white noise: the formula covers
    // it (0.79-1.16), the spread a little more (0.91-1.46). Blobs of 6 px, longer
    // than a stretch, are covered to 0.71-0.87.
    let (error, formula, robust) = free_fit_errors(30, 3.0);
    assert!(formula < 0.65 * error, "{error} {formula}");
    assert!(
        robust > 0.75 * error && robust < 1.35 * error,
        "{error} {robust}"
    );
    let (error, formula, robust) = free_fit_errors(30, 0.5);
    assert!(
        formula > 0.7 * error && formula < 1.3 * error,
        "{error} {formula}"
    );
    assert!(
        robust >= formula && robust < 1.5 * error,
        "{error} {robust}"
    );
}

/// The strip's fit with tied edges, each edge's calibration error `sigma` (radians)
/// both weighing it and reported.
fn tied_fit(img: &GrayImage, sigma: PerEdge<f64>, noise0: Option<PerEdge<f64>>) -> FitResult {
    Refiner::default()
        .fit(
            img,
            &strip_bands(),
            Turns::Tied(Tie {
                weigh: sigma,
                error: sigma,
            }),
            1.0,
            noise0,
            false,
        )
        .unwrap()
}

#[test]
fn tied_edges_give_the_calibration_weighted_mean_and_its_error() {
    // The two edges disagree by 0.2 deg, more than either frame measurement's error:
    // with calibration errors of 0.1 and 0.01 deg the tip turns (nearly) with the
    // better-calibrated edge, by the generalised least-squares mean, and its
    // standard error is at least the calibration's share.
    let (top, bottom) = (0.2f64.to_radians(), 0.0);
    let img = strip(top, bottom, 1.0);
    let sigma = [f64::NAN, 0.1f64.to_radians(), 0.01f64.to_radians()];
    let fit = tied_fit(&img, sigma, None);
    // The frame measures each edge to a few thousandths of a degree here, so the
    // tie hardly moves them, and the tip's turn is their calibration-weighted mean.
    let [_, Some(b), Some(g)] = fit.edges else {
        panic!("both edges fitted")
    };
    assert!(
        (b.turn - top).abs().to_degrees() < 0.01,
        "{}",
        b.turn.to_degrees()
    );
    assert!(
        (g.turn - bottom).abs().to_degrees() < 0.01,
        "{}",
        g.turn.to_degrees()
    );
    let (wb, wg) = (sigma[1].powi(-2), sigma[2].powi(-2));
    let expected = (wb * b.turn + wg * g.turn) / (wb + wg);
    assert!(
        (fit.turn - expected).abs() < 1e-9,
        "{} {}",
        fit.turn,
        expected
    );
    let calibration_share = (wb + wg).recip().sqrt();
    assert!(fit.turn_sigma >= calibration_share);
    assert!(
        fit.turn_sigma < 1.1 * calibration_share,
        "{}",
        fit.turn_sigma
    );
    // Shared, the same edges are forced to one rotation between the two.
    let shared = Refiner::default()
        .fit(&img, &strip_bands(), Turns::Shared, 1.0, None, false)
        .unwrap();
    let mid = shared.turn.to_degrees();
    assert!(mid > 0.05 && mid < 0.15, "{mid}");
}

#[test]
fn a_fit_started_from_the_measured_noise_lands_where_a_cold_one_does() {
    // A noisy strip (sigma 25 grey levels, deterministic) with a bright blob on the
    // outside of the top edge, turned 1.5 deg from the level bands: the tracker's
    // final fit starts from the coarse pass's noise, and must reach the same
    // rotation and standard error as a fit that measures the noise itself (here
    // they agree to 0.0001 sigma).
    let (top, bottom) = (1.5f64.to_radians(), 1.5f64.to_radians());
    let mut img = strip(top, bottom, 1.2);
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    for (x, y, p) in img.enumerate_pixels_mut() {
        let gauss = (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
        let blob = if (x as f64 - 60.0).hypot(y as f64 - 44.0) < 4.0 {
            90.0
        } else {
            0.0
        };
        p.0[0] = (p.0[0] as f64 + 25.0 * gauss + blob)
            .round()
            .clamp(0.0, 255.0) as u8;
    }
    let sigma = [f64::NAN, 0.02f64.to_radians(), 0.02f64.to_radians()];
    let cold = tied_fit(&img, sigma, None);
    let noise = cold.noise();
    assert!(noise[1] > 20.0 && noise[1] < 30.0, "{noise:?}");
    let warm = tied_fit(&img, sigma, Some(noise));
    assert!(
        (warm.turn - cold.turn).abs() < 0.02 * cold.turn_sigma,
        "warm {} cold {} sigma {}",
        warm.turn.to_degrees(),
        cold.turn.to_degrees(),
        cold.turn_sigma.to_degrees()
    );
    assert!((warm.turn_sigma / cold.turn_sigma - 1.0).abs() < 0.05);
    // Both near the truth.
    assert!((cold.turn - top).abs() < 4.0 * cold.turn_sigma);
}
