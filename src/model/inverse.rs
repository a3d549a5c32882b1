//! Exact inverses of the elastica by root-finding on the closed form (never on the lookup
//! table): the tip slope that carries a given load, or that gives a given tip deflection.
//! The simulated plant imposes a tip deflection and needs the true slope and force.

use super::elastica::{alpha_of, delta_of, ModelError, MAX_PHI0_RAD};

/// The tip slope phi0 (radians, sign of `alpha`) at which the nondimensional tip load
/// F L^2 / EI equals `alpha`. Accurate to a few ulp; |alpha| must not exceed the load at
/// 89 deg ([`max_alpha`]).
pub fn phi0_from_alpha(alpha: f64) -> Result<f64, ModelError> {
    let max = max_alpha();
    let target = alpha.abs();
    if target.is_nan() || target > max {
        return Err(ModelError::LoadOutOfRange { alpha, max });
    }
    Ok(phi0_of_alpha(target).copysign(alpha))
}

/// phi0 >= 0 for a load 0 <= alpha <= [`max_alpha`], unchecked.
pub(crate) fn phi0_of_alpha(alpha: f64) -> f64 {
    if alpha == 0.0 {
        return 0.0;
    }
    // R >= 1 gives alpha >= 2 sin(phi0): an upper bound that is tight for small loads.
    let upper = (alpha / 2.0).min(1.0).asin().min(MAX_PHI0_RAD);
    solve_increasing(|p| alpha_of(p) - alpha, 0.0, upper)
}

/// The tip slope phi0 (radians, sign of `delta_over_l`) at which the tip deflection is
/// `delta_over_l` (transverse, over L). |delta/L| must not exceed the deflection at 89 deg
/// ([`max_delta_over_l`]).
pub fn phi0_from_deflection(delta_over_l: f64) -> Result<f64, ModelError> {
    let max = max_delta_over_l();
    let target = delta_over_l.abs();
    if target.is_nan() || target > max {
        return Err(ModelError::DeflectionOutOfRange { delta_over_l, max });
    }
    if target == 0.0 {
        return Ok(delta_over_l);
    }
    // delta/L = s0 (1 - c0^2 R_D / (3 R)) lies between 2 s0 / 3 and s0.
    let lower = target.min(1.0).asin().min(MAX_PHI0_RAD);
    let upper = (1.5 * target).min(1.0).asin().min(MAX_PHI0_RAD);
    let objective = |p| delta_of(p) - target;
    let upper = if objective(upper) >= 0.0 {
        upper
    } else {
        MAX_PHI0_RAD
    };
    let lower = if objective(lower) <= 0.0 { lower } else { 0.0 };
    Ok(solve_increasing(objective, lower, upper).copysign(delta_over_l))
}

/// The nondimensional load at the largest slope the model accepts (89 deg), ~27.52.
pub fn max_alpha() -> f64 {
    alpha_of(MAX_PHI0_RAD)
}

/// The tip deflection over L at the largest slope the model accepts (89 deg), ~0.888.
pub fn max_delta_over_l() -> f64 {
    delta_of(MAX_PHI0_RAD)
}

/// Root of an increasing `f` in [lo, hi] with f(lo) <= 0 <= f(hi), to a relative
/// tolerance of 2 ulp, by Brent's method (inverse quadratic interpolation, secant steps,
/// bisection as the safeguard).
pub(crate) fn solve_increasing(f: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
    let (mut a, mut b) = (lo, hi);
    let (mut fa, mut fb) = (f(a), f(b));
    if fa >= 0.0 {
        return a;
    }
    if fb <= 0.0 {
        return b;
    }
    let (mut c, mut fc) = (a, fa);
    let mut step = b - a;
    let mut previous_step = step;
    for _ in 0..200 {
        if (fb > 0.0) == (fc > 0.0) {
            (c, fc) = (a, fa);
            step = b - a;
            previous_step = step;
        }
        if fc.abs() < fb.abs() {
            (a, fa) = (b, fb);
            (b, fb) = (c, fc);
            (c, fc) = (a, fa);
        }
        let tol = 2.0 * f64::EPSILON * b.abs() + f64::MIN_POSITIVE;
        let half = 0.5 * (c - b);
        if half.abs() <= tol || fb == 0.0 {
            return b;
        }
        if previous_step.abs() >= tol && fa.abs() > fb.abs() {
            let (p, q) = interpolation_step(a, b, c, fa, fb, fc, half);
            let (p, q) = if p > 0.0 { (p, -q) } else { (-p, q) };
            if 2.0 * p < (3.0 * half * q - (tol * q).abs()).min((previous_step * q).abs()) {
                previous_step = step;
                step = p / q;
            } else {
                step = half;
                previous_step = half;
            }
        } else {
            step = half;
            previous_step = half;
        }
        (a, fa) = (b, fb);
        b += if step.abs() > tol {
            step
        } else {
            tol.copysign(half)
        };
        fb = f(b);
    }
    b
}

/// Brent's interpolation step p / q: secant through (a, b), or inverse quadratic through
/// (a, b, c) when the three are distinct.
fn interpolation_step(a: f64, b: f64, c: f64, fa: f64, fb: f64, fc: f64, half: f64) -> (f64, f64) {
    let s = fb / fa;
    if a == c {
        (2.0 * half * s, 1.0 - s)
    } else {
        let q = fa / fc;
        let r = fb / fc;
        let p = s * (2.0 * half * q * (q - r) - (b - a) * (r - 1.0));
        (p, (q - 1.0) * (r - 1.0) * (s - 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::exact;
    use proptest::prelude::*;

    #[test]
    fn limits_are_the_values_at_89_degrees() {
        let e = exact(MAX_PHI0_RAD).unwrap();
        assert_eq!(max_alpha(), e.alpha);
        assert_eq!(max_delta_over_l(), e.delta_over_l);
        assert!((max_alpha() - 27.524_309_308_362_2).abs() < 1e-12);
        assert_eq!(phi0_from_alpha(max_alpha()), Ok(MAX_PHI0_RAD));
        assert!((phi0_from_deflection(-max_delta_over_l()).unwrap() + MAX_PHI0_RAD).abs() < 1e-15);
    }

    #[test]
    fn out_of_range_requests_are_errors() {
        for alpha in [30.0, -1e9, f64::NAN, f64::INFINITY] {
            let err = phi0_from_alpha(alpha).unwrap_err();
            assert!(matches!(err, ModelError::LoadOutOfRange { .. }), "{err}");
        }
        let msg = phi0_from_deflection(0.95).unwrap_err().to_string();
        assert!(
            msg.contains("delta/L = 0.95") && msg.contains("89 deg"),
            "{msg}"
        );
        assert_eq!(
            phi0_from_alpha(-0.0).map(f64::to_bits),
            Ok((-0.0f64).to_bits())
        );
    }

    #[test]
    fn tiny_loads_and_deflections_keep_relative_precision() {
        for phi0 in [1e-300, 1e-100, 1e-12, 1e-6] {
            let e = exact(phi0).unwrap();
            let from_alpha = phi0_from_alpha(e.alpha).unwrap();
            let from_delta = phi0_from_deflection(e.delta_over_l).unwrap();
            assert!(
                (from_alpha / phi0 - 1.0).abs() < 1e-15,
                "{phi0}: {from_alpha}"
            );
            assert!(
                (from_delta / phi0 - 1.0).abs() < 1e-15,
                "{phi0}: {from_delta}"
            );
        }
    }

    proptest! {
        #[test]
        fn inverses_round_trip(phi0 in -MAX_PHI0_RAD..=MAX_PHI0_RAD) {
            let e = exact(phi0).unwrap();
            let from_alpha = phi0_from_alpha(e.alpha).unwrap();
            let from_delta = phi0_from_deflection(e.delta_over_l).unwrap();
            prop_assert!((from_alpha - phi0).abs() <= 1e-14 * phi0.abs(), "{} vs {}", from_alpha, phi0);
            prop_assert!((from_delta - phi0).abs() <= 1e-14 * phi0.abs(), "{} vs {}", from_delta, phi0);
        }

        #[test]
        fn forward_of_inverse_is_identity(alpha in -27.5..27.5f64) {
            let phi0 = phi0_from_alpha(alpha).unwrap();
            let back = exact(phi0).unwrap().alpha;
            prop_assert!((back - alpha).abs() <= 1e-14 * alpha.abs(), "{} vs {}", back, alpha);
        }
    }
}
