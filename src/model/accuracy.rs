//! Accuracy of the closed form (test builds only): against the 40-digit reference values
//! in tests/data/elastica.csv, against quadrature of the paper's corrected Eqs. 9 and 10
//! at thousands of angles, and the centreline against the beam equation.

use super::reference::{centreline_by_ode, elastica_by_quadrature, SplitMix};
use super::{centreline, exact, slope_rad, Centreline, Elastica, MAX_PHI0_RAD};

fn rel(got: f64, want: f64) -> f64 {
    (got / want - 1.0).abs()
}

fn as_array(e: Elastica) -> [f64; 3] {
    [e.alpha, e.delta_over_l, e.shortening_over_l]
}

/// Worst relative error of exact() against `reference` over `angles_rad`, per quantity.
fn worst_against(angles_rad: &[f64], reference: impl Fn(f64) -> [f64; 3]) -> [(f64, f64); 3] {
    let mut worst = [(0.0, 0.0); 3];
    for &phi0 in angles_rad {
        let got = as_array(exact(phi0).expect("angles within range"));
        for (m, want) in reference(phi0).into_iter().enumerate() {
            let err = rel(got[m], want);
            if err > worst[m].0 {
                worst[m] = (err, phi0.to_degrees());
            }
        }
    }
    worst
}

#[test]
fn exact_matches_the_40_digit_reference_table() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/elastica.csv");
    let text = std::fs::read_to_string(path).expect("tests/data/elastica.csv is in the repo");
    let mut rows = 0;
    for line in text.lines().skip(1) {
        let v: Vec<f64> = line
            .split(',')
            .map(|f| f.parse().expect("numeric CSV"))
            .collect();
        let got = as_array(exact(v[0].to_radians()).expect("in range"));
        for m in 0..3 {
            // The file holds 17 significant digits; angle_deg -> radians rounds once.
            assert!(
                rel(got[m], v[m + 1]) < 2e-15,
                "{line}: column {m} got {:e}",
                got[m]
            );
        }
        rows += 1;
    }
    assert_eq!(rows, 17);
}

/// 1000 log-spaced angles from 1e-3 to 85 deg, 2000 uniform random ones in (0, 85] and
/// 500 log-uniform random ones in [1e-8, 1] deg.
fn test_angles_rad() -> Vec<f64> {
    let mut rng = SplitMix(0x5EED_E1A5);
    let log_spaced = (0..1000).map(|i| 1e-3 * (85e3f64).powf(i as f64 / 999.0));
    let uniform: Vec<f64> = (0..2000).map(|_| 85.0 * (1.0 - rng.next_f64())).collect();
    let small: Vec<f64> = (0..500)
        .map(|_| 10f64.powf(-8.0 * rng.next_f64()))
        .collect();
    log_spaced
        .chain(uniform)
        .chain(small)
        .map(f64::to_radians)
        .collect()
}

#[test]
fn exact_matches_quadrature_of_the_corrected_equations() {
    let angles = test_angles_rad();
    assert!(angles.len() >= 3500);
    let worst = worst_against(&angles, elastica_by_quadrature);
    eprintln!("exact vs quadrature, 0.001..85 deg: worst (relative error, angle_deg) {worst:?}");
    for (m, (err, deg)) in worst.into_iter().enumerate() {
        assert!(
            err < 1e-13,
            "quantity {m}: relative error {err:e} at {deg} deg"
        );
    }
}

#[test]
fn exact_matches_quadrature_up_to_89_degrees_and_at_tiny_angles() {
    let near_limit: Vec<f64> = (0..=400)
        .map(|i| (85.0 + 4.0 * i as f64 / 400.0).to_radians())
        .collect();
    let worst = worst_against(&near_limit, elastica_by_quadrature);
    eprintln!("exact vs quadrature, 85..89 deg: worst {worst:?}");
    for (err, deg) in worst {
        assert!(err < 1e-12, "relative error {err:e} at {deg} deg");
    }
    // Down to 1e-150 rad every quantity keeps full relative precision.
    let tiny: Vec<f64> = (1..=15).map(|i| 10f64.powi(-10 * i)).collect();
    let worst = worst_against(&tiny, |p| {
        // Series: alpha = 2p(1 + p^2/...), delta = 2p/3, Delta = 4p^2/15 to O(p^2) relative.
        [2.0 * p, 2.0 * p / 3.0, 4.0 * p * p / 15.0]
    });
    for (err, deg) in worst {
        assert!(err < 1e-15, "relative error {err:e} at {deg} deg");
    }
}

#[test]
fn centreline_solves_the_beam_equation() {
    let steps = 4000;
    for deg in [0.01, 1.0, 10.0, 20.0, 45.0, 70.0, 85.0, 89.0] {
        let phi0 = f64::to_radians(deg);
        let alpha = exact(phi0).expect("in range").alpha;
        let path = centreline_by_ode(alpha, phi0, steps);
        let line = Centreline::new(phi0);
        let mut worst: f64 = 0.0;
        for (i, &[phi, x, y]) in path.iter().enumerate().step_by(40) {
            let s = i as f64 / steps as f64;
            let [cx, cy] = line.point(s);
            worst = worst.max((cx - x).abs()).max((cy - y).abs());
            worst = worst.max((line.slope_rad(s) - phi).abs());
        }
        // RK4 with h = 1/4000 is good to ~1e-12 at 89 deg (alpha = 27.5).
        assert!(
            worst < 1e-11,
            "{deg} deg: worst absolute difference {worst:e}"
        );
    }
}

#[test]
fn centreline_ends_where_exact_says() {
    for deg in [-89.0, -30.0, -1e-3, 1e-6, 0.5, 20.0, 60.0, 89.0] {
        let phi0 = f64::to_radians(deg);
        let e = exact(phi0).expect("in range");
        let [x, y] = centreline(phi0, 1.0);
        assert!(
            (x - (1.0 - e.shortening_over_l)).abs() < 1e-15,
            "{deg}: x {x}"
        );
        assert!(
            (y - e.delta_over_l).abs() <= 1e-15 * e.delta_over_l.abs(),
            "{deg}: y {y}"
        );
        let [x0, y0] = centreline(phi0, 0.0);
        assert!(
            x0.abs() < 1e-15 && y0.abs() < 1e-15,
            "{deg}: clamp at {x0}, {y0}"
        );
        assert!((slope_rad(phi0, 1.0) - phi0).abs() < 1e-15, "{deg}");
        // At the clamp the Jacobi amplitude is near pi/2, where cn ~ k' = 0.009 at 89 deg
        // carries an absolute error of ~1e-16 / k'^2 from the AGM's arcsines.
        let clamp_slope = slope_rad(phi0, 0.0);
        assert!(
            clamp_slope.abs() < 5e-12,
            "{deg}: slope at the clamp {clamp_slope:e}"
        );
    }
}

#[test]
fn centreline_is_symmetric_and_saturates() {
    let [x, y] = centreline(0.3, 0.4);
    assert_eq!(centreline(-0.3, 0.4), [x, -y]);
    assert_eq!(slope_rad(-0.3, 0.4), -slope_rad(0.3, 0.4));
    assert_eq!(centreline(2.0, 0.5), centreline(MAX_PHI0_RAD, 0.5));
    assert_eq!(centreline(0.3, 1.5), centreline(0.3, 1.0));
    assert_eq!(centreline(0.0, 0.25), [0.25, 0.0]);
    // Tiny slopes: no underflow trouble, the linear-theory shape y = alpha s^2 (3 - s) / 6.
    for phi0 in [1e-300, 1e-12] {
        let [x, y] = centreline(phi0, 0.5);
        let alpha = 2.0 * phi0;
        assert!((x - 0.5).abs() < 1e-15, "{phi0}: x {x}");
        assert!(
            (y / (alpha * 0.25 * 2.5 / 6.0) - 1.0).abs() < 1e-12,
            "{phi0}: y {y}"
        );
    }
    assert!(centreline(f64::NAN, 0.5).iter().all(|v| v.is_nan()));
    assert!(centreline(0.3, f64::NAN).iter().all(|v| v.is_nan()));
    assert!(slope_rad(f64::NAN, 0.5).is_nan());
}
