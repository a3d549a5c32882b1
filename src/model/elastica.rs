//! The exact large-deflection elastica of a cantilever (length L, rigidity EI) clamped at
//! the origin with zero slope and loaded at its free end by a force F of fixed direction,
//! transverse to the undeformed beam (the paper's Eqs. 1-10, corrected in docs/model.md).
//!
//! With alpha = F L^2 / EI, s0 = sin(phi0), c0 = cos(phi0) and the Carlson integrals
//! R = R_F(1 - s0, 1 + s0, c0^2), R_D = R_D(1 - s0, 1 + s0, c0^2):
//!
//! - alpha = 2 s0 R^2 (Eq. 9: sqrt(alpha) = int_0^phi0 dphi / sqrt(2 (s0 - sin phi)));
//! - delta / L = s0 (1 - c0^2 R_D / (3 R)) (Eq. 10 with the square root restored);
//! - (L - Delta) / L = sqrt(2 s0 / alpha) = 1 / R, so Delta / L = (R - 1) / R.
//!
//! These are the Bisshopp-Drucker solution sqrt(alpha) = K(k) - F(theta1, k),
//! delta/L = 1 - 2 (E(k) - E(theta1, k)) / sqrt(alpha), k^2 = (1 + s0)/2,
//! sin(theta1) = 1/(sqrt(2) k), rewritten so that no term cancels as phi0 -> 0
//! (docs/model.md derives them). The slope and shape at arclength s follow from the
//! Jacobi functions of v = sqrt(alpha) (1 - s/L) with modulus k, see [`Centreline`].

use super::carlson::{rd, rf_minus_one};
use super::jacobi::jacobi;

/// Largest tip slope the model accepts, degrees (alpha grows without bound toward 90).
pub const MAX_PHI0_DEG: f64 = 89.0;
/// [`MAX_PHI0_DEG`] in radians, bit-identical to `MAX_PHI0_DEG.to_radians()`.
pub const MAX_PHI0_RAD: f64 = MAX_PHI0_DEG * (std::f64::consts::PI / 180.0);

/// The nondimensional state of the beam for one tip slope phi0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Elastica {
    /// Nondimensional tip load F L^2 / EI; odd in phi0.
    pub alpha: f64,
    /// Tip deflection transverse to the undeformed beam over L; odd in phi0.
    pub delta_over_l: f64,
    /// Projected shortening of the beam along its undeformed axis over L; even in phi0.
    pub shortening_over_l: f64,
}

/// A request outside the model's range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("tip slope {phi0_deg} deg is outside the model's range |phi0| <= {MAX_PHI0_DEG} deg")]
    AngleOutOfRange { phi0_deg: f64 },
    #[error(
        "nondimensional load alpha = {alpha} is outside the model's range |alpha| <= {max} \
         (the load at a tip slope of {MAX_PHI0_DEG} deg)"
    )]
    LoadOutOfRange { alpha: f64, max: f64 },
    #[error(
        "tip deflection delta/L = {delta_over_l} is outside the model's range \
         |delta/L| <= {max} (the deflection at a tip slope of {MAX_PHI0_DEG} deg)"
    )]
    DeflectionOutOfRange { delta_over_l: f64, max: f64 },
}

/// The exact elastica for a tip slope `phi0_rad` (radians, either sign, |phi0| <= 89 deg).
/// Relative accuracy a few 1e-15 (tested against quadrature) for every |phi0| >= 1e-150
/// rad, where Delta/L is still a normal float; NaN and out-of-range slopes
/// are errors.
pub fn exact(phi0_rad: f64) -> Result<Elastica, ModelError> {
    let magnitude = checked_magnitude(phi0_rad)?;
    let e = Shape::new(magnitude).elastica();
    Ok(Elastica {
        alpha: e.alpha.copysign(phi0_rad),
        delta_over_l: e.delta_over_l.copysign(phi0_rad),
        shortening_over_l: e.shortening_over_l,
    })
}

/// |phi0| if it is within the model's range.
fn checked_magnitude(phi0_rad: f64) -> Result<f64, ModelError> {
    let magnitude = phi0_rad.abs();
    if magnitude <= MAX_PHI0_RAD {
        Ok(magnitude)
    } else {
        Err(ModelError::AngleOutOfRange {
            phi0_deg: phi0_rad.to_degrees(),
        })
    }
}

/// The elastica for 0 <= phi0 <= 89 deg, unchecked (the table's sampler).
pub(crate) fn elastica_of(phi0_rad: f64) -> Elastica {
    Shape::new(phi0_rad).elastica()
}

/// alpha for 0 <= phi0 <= 89 deg, computing R only (the inverse solvers' objective).
pub(crate) fn alpha_of(phi0_rad: f64) -> f64 {
    let shape = Shape::new(phi0_rad);
    2.0 * shape.sin * shape.r * shape.r
}

/// delta / L for 0 <= phi0 <= 89 deg.
pub(crate) fn delta_of(phi0_rad: f64) -> f64 {
    elastica_of(phi0_rad).delta_over_l
}

/// The quantities every formula shares, for 0 <= phi0 <= 89 deg.
#[derive(Debug, Clone, Copy)]
struct Shape {
    sin: f64,
    cos: f64,
    /// Elliptic modulus k = sqrt((1 + s0)/2) = cos(pi/4 - phi0/2) and k' = sin(pi/4 - phi0/2).
    k: f64,
    k_prime: f64,
    /// R_F(1 - s0, 1 + s0, c0^2) - 1 and R_F itself.
    r_minus_one: f64,
    r: f64,
}

impl Shape {
    fn new(phi0_rad: f64) -> Shape {
        let (sin, cos) = phi0_rad.sin_cos();
        let (k_prime, k) = (std::f64::consts::FRAC_PI_4 - phi0_rad / 2.0).sin_cos();
        // 1 - s0 = 2 k'^2 and 1 + s0 = 2 k^2 without rounding loss near 90 deg.
        let args = [2.0 * k_prime * k_prime, 2.0 * k * k, cos * cos];
        let r_minus_one = rf_minus_one(args, [sin, -sin, sin * sin]);
        Shape {
            sin,
            cos,
            k,
            k_prime,
            r_minus_one,
            r: 1.0 + r_minus_one,
        }
    }

    fn rd(&self) -> f64 {
        rd(
            2.0 * self.k_prime * self.k_prime,
            2.0 * self.k * self.k,
            self.cos * self.cos,
        )
    }

    fn elastica(&self) -> Elastica {
        let cos2 = self.cos * self.cos;
        Elastica {
            alpha: 2.0 * self.sin * self.r * self.r,
            delta_over_l: self.sin * (1.0 - cos2 * self.rd() / (3.0 * self.r)),
            shortening_over_l: self.r_minus_one / self.r,
        }
    }
}

/// The deflected centreline for one tip slope, for evaluating many points along the beam
/// (the free functions [`centreline`] and [`slope_rad`] build one per call).
///
/// Coordinates are over L: x along the undeformed beam from the clamp, y transverse with
/// the sign of phi0. Out-of-range input saturates: |phi0| is clamped to 89 deg and s/L to
/// [0, 1]; NaN gives NaN.
#[derive(Debug, Clone, Copy)]
pub struct Centreline {
    sign: f64,
    shape: Shape,
    sqrt_alpha: f64,
    delta_over_l: f64,
}

impl Centreline {
    pub fn new(phi0_rad: f64) -> Centreline {
        // f64::min would turn NaN into the limit; NaN must stay NaN.
        let magnitude = if phi0_rad.is_nan() {
            f64::NAN
        } else {
            phi0_rad.abs().min(MAX_PHI0_RAD)
        };
        let shape = Shape::new(magnitude);
        let e = shape.elastica();
        Centreline {
            sign: 1.0f64.copysign(phi0_rad),
            shape,
            sqrt_alpha: e.alpha.sqrt(),
            delta_over_l: e.delta_over_l,
        }
    }

    /// [x/L, y/L] of the centreline at arclength fraction `s_over_l` (0 = clamp, 1 = tip).
    pub fn point(&self, s_over_l: f64) -> [f64; 2] {
        let s_over_l = s_over_l.clamp(0.0, 1.0);
        let Shape { sin, cos, .. } = self.shape;
        if sin == 0.0 {
            return [s_over_l, 0.0];
        }
        // Arclength from the tip: v = sqrt(alpha) (1 - s/L) = F(am v, k), and along the
        // beam 1 + sin(phi) = 2 k^2 cd^2(v).
        let v = self.sqrt_alpha * (1.0 - s_over_l);
        let j = jacobi(v, self.shape.k, self.shape.k_prime);
        // x: from (L - x)/L-type integral of cos(phi) ds = d(sqrt(s0 - sin phi)).
        let x = ((2.0 * sin).sqrt() - cos * j.sn / j.dn) / self.sqrt_alpha;
        // y: delta/L minus the integral of sin(phi) ds from s to the tip.
        // The integral is (s0 v - c0^2 sn^3 R_D(cn^2, 1, dn^2) / 6) / sqrt(alpha), written
        // with sn / sqrt(alpha) ~ 1 - s/L so that nothing underflows at tiny phi0.
        let sn_scaled = j.sn / self.sqrt_alpha;
        let alpha = self.sqrt_alpha * self.sqrt_alpha;
        let tail_rd = rd(j.cn * j.cn, 1.0, j.dn * j.dn);
        let tail = sin * (1.0 - s_over_l) - cos * cos * alpha * sn_scaled.powi(3) * tail_rd / 6.0;
        let y = self.delta_over_l - tail;
        [x, self.sign * y]
    }

    /// Slope of the centreline (radians from the undeformed axis, sign of phi0) at
    /// arclength fraction `s_over_l`: 0 at the clamp, phi0 at the tip.
    pub fn slope_rad(&self, s_over_l: f64) -> f64 {
        let s_over_l = s_over_l.clamp(0.0, 1.0);
        let Shape { sin, cos, .. } = self.shape;
        if sin == 0.0 {
            return 0.0;
        }
        let v = self.sqrt_alpha * (1.0 - s_over_l);
        let j = jacobi(v, self.shape.k, self.shape.k_prime);
        // sin(phi) dn^2 = s0 - (1 + s0) sn^2 / 2 and cos(phi) dn^2 = c0 cn.
        let slope = (2.0 * sin - (1.0 + sin) * j.sn * j.sn).atan2(2.0 * cos * j.cn);
        self.sign * slope
    }
}

/// The deflected beam's centreline point [x/L, y/L] at arclength fraction `s_over_l` for a
/// tip slope `phi0_rad`: the clamp is at the origin with zero slope, x runs along the
/// undeformed beam, y is transverse with the sign of phi0, and
/// `centreline(phi0, 1.0)` = [1 - Delta/L, delta/L]. Saturating as in [`Centreline`].
pub fn centreline(phi0_rad: f64, s_over_l: f64) -> [f64; 2] {
    Centreline::new(phi0_rad).point(s_over_l)
}

/// The beam's slope (radians) at arclength fraction `s_over_l` for a tip slope `phi0_rad`.
/// Saturating as in [`Centreline`].
pub fn slope_rad(phi0_rad: f64, s_over_l: f64) -> f64 {
    Centreline::new(phi0_rad).slope_rad(s_over_l)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn out_of_range_slopes_are_errors_not_panics() {
        for phi0_deg in [89.000_001, -90.0, 1e3, f64::INFINITY] {
            let err = exact(phi0_deg.to_radians()).unwrap_err();
            assert!(matches!(err, ModelError::AngleOutOfRange { .. }), "{err}");
        }
        let msg = exact(f64::NAN).unwrap_err().to_string();
        assert!(
            msg.contains("NaN deg") && msg.contains("<= 89 deg"),
            "{msg}"
        );
        let msg = exact(95f64.to_radians()).unwrap_err().to_string();
        assert!(msg.starts_with("tip slope 95"), "{msg}");
        assert!(exact(MAX_PHI0_RAD).is_ok() && exact(-MAX_PHI0_RAD).is_ok());
        assert_eq!(MAX_PHI0_RAD, MAX_PHI0_DEG.to_radians());
    }

    #[test]
    fn zero_slope_is_the_unloaded_beam() {
        let e = exact(0.0).unwrap();
        assert_eq!(
            (e.alpha, e.delta_over_l, e.shortening_over_l),
            (0.0, 0.0, 0.0)
        );
        assert_eq!(centreline(0.0, 1.0), [1.0, 0.0]);
    }

    /// Linear beam theory is the small-angle limit: F = 3 EI delta / L^3 and
    /// phi0 = F L^2 / (2 EI), so alpha = 2 phi0 and delta/L = alpha/3.
    #[test]
    fn small_slopes_follow_linear_beam_theory() {
        let phi0 = 1e-7;
        let e = exact(phi0).unwrap();
        assert!((e.alpha / (2.0 * phi0) - 1.0).abs() < 1e-13);
        assert!((e.delta_over_l / (e.alpha / 3.0) - 1.0).abs() < 1e-13);
    }

    proptest! {
        #[test]
        fn alpha_and_deflection_are_odd_shortening_even(phi0 in -MAX_PHI0_RAD..=MAX_PHI0_RAD) {
            let (plus, minus) = (exact(phi0).unwrap(), exact(-phi0).unwrap());
            prop_assert_eq!(minus.alpha, -plus.alpha);
            prop_assert_eq!(minus.delta_over_l, -plus.delta_over_l);
            prop_assert_eq!(minus.shortening_over_l, plus.shortening_over_l);
            prop_assert!(plus.alpha * phi0 >= 0.0 && plus.delta_over_l * phi0 >= 0.0);
            prop_assert!(plus.shortening_over_l >= 0.0);
        }

        #[test]
        fn every_quantity_increases_with_the_slope(a in 0.0..=MAX_PHI0_RAD, b in 0.0..=MAX_PHI0_RAD) {
            let (lo, hi) = (a.min(b), a.max(b));
            prop_assume!(hi > lo * (1.0 + 1e-12) + 1e-300);
            let (el, eh) = (exact(lo).unwrap(), exact(hi).unwrap());
            prop_assert!(el.alpha < eh.alpha, "alpha {} vs {}", el.alpha, eh.alpha);
            prop_assert!(el.delta_over_l < eh.delta_over_l);
            prop_assert!(el.shortening_over_l < eh.shortening_over_l);
        }

        #[test]
        fn the_beam_keeps_its_length(phi0 in -MAX_PHI0_RAD..=MAX_PHI0_RAD) {
            // Chords between points 1/64 apart are shorter than the arc, by less than
            // curvature^2 h^3 / 24 (the curvature is at most sqrt(2 alpha)).
            let line = Centreline::new(phi0);
            let h = 1.0 / 64.0;
            let alpha = exact(phi0).unwrap().alpha.abs();
            let mut length = 0.0;
            let mut previous = line.point(0.0);
            for i in 1..=64 {
                let p = line.point(i as f64 * h);
                length += (p[0] - previous[0]).hypot(p[1] - previous[1]);
                previous = p;
            }
            prop_assert!(length <= 1.0 + 1e-14, "length {}", length);
            prop_assert!(length >= 1.0 - 64.0 * 2.0 * alpha * h.powi(3) / 24.0 - 1e-14, "length {}", length);
        }
    }
}
