//! The lookup table the paper calls for: built once at start-up from the exact elastica,
//! then angle -> (alpha, delta/L, Delta/L) and load -> angle in a few dozen nanoseconds,
//! with a relative error below 1e-13 over the whole range (tested to 1e-9 everywhere).
//!
//! Design (docs/model.md has the measurements):
//! - Forward, the variable is tau = -ln(1 - phi0 / (pi/2)). alpha has a logarithmic
//!   singularity at 90 deg; in tau it grows like tau^2 and every function is analytic in
//!   a strip around the real axis, so a uniform mesh in tau is a geometric mesh in
//!   phi0 graded toward 90 deg.
//! - Inverse, the variable is w = sqrt(alpha), in which phi0 approaches 90 deg like
//!   exp(-w) and is smooth everywhere.
//! - Interpolated are the ratios alpha/phi0, delta/(L phi0), Delta/(L phi0^2) and
//!   phi0/alpha, which tend to constants at 0, so relative precision holds down to the
//!   smallest angles and the values are exactly odd/even in phi0.
//! - Each is a piecewise Chebyshev interpolant of degree 12 ([`super::chebyshev`]).
//! - Out of range (|phi0| > 89 deg, |alpha| > alpha(89 deg), NaN) a lookup returns the
//!   value at the limit with `saturated` set; it never extrapolates.

use std::f64::consts::FRAC_PI_2;
use std::sync::OnceLock;

use super::chebyshev::Piecewise;
use super::elastica::{elastica_of, Elastica, MAX_PHI0_RAD};
use super::inverse::{max_alpha, phi0_of_alpha};

/// Pieces of each interpolant; with degree 12 either table is exact to rounding (the
/// tests show 1e-13 at 16 pieces too; 24 leaves a margin for nothing extra in cost).
const FORWARD_PIECES: usize = 24;
const INVERSE_PIECES: usize = 24;

/// A table value, and whether the request was outside the table's range (then `value`
/// is the value at the range's limit with the request's sign, or NaN for a NaN request).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lookup<T> {
    pub value: T,
    pub saturated: bool,
}

impl<T> Lookup<T> {
    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> Lookup<U> {
        Lookup {
            value: f(self.value),
            saturated: self.saturated,
        }
    }
}

/// The precomputed cantilever model; see the module docs. Build it once
/// ([`ModelTable::global`] shares one per process) and look up from any thread.
#[derive(Debug, Clone)]
pub struct ModelTable {
    /// [alpha/phi0, delta/(L phi0), Delta/(L phi0^2)] against tau.
    forward: Piecewise<3>,
    /// phi0/alpha against sqrt(alpha).
    inverse: Piecewise<1>,
    max_tau: f64,
    max_alpha: f64,
}

/// tau = -ln(1 - phi0 / (pi/2)) for 0 <= phi0 < pi/2.
#[inline]
fn tau_of(phi0_rad: f64) -> f64 {
    -(-phi0_rad / FRAC_PI_2).ln_1p()
}

impl ModelTable {
    /// Samples the exact model (about 600 closed-form evaluations and 300 root solves).
    pub fn build() -> ModelTable {
        let max_tau = tau_of(MAX_PHI0_RAD);
        let forward = Piecewise::build(0.0, max_tau, FORWARD_PIECES, |tau| {
            let phi0 = -FRAC_PI_2 * (-tau).exp_m1();
            let e = elastica_of(phi0);
            [
                e.alpha / phi0,
                e.delta_over_l / phi0,
                e.shortening_over_l / (phi0 * phi0),
            ]
        });
        // The exact load at 89 deg, or the forward table's if rounding made that larger, so
        // that any load the table returns maps back without saturating.
        let max_alpha = max_alpha().max(forward.eval(max_tau)[0] * MAX_PHI0_RAD);
        let inverse = Piecewise::build(0.0, max_alpha.sqrt(), INVERSE_PIECES, |w| {
            let alpha = w * w;
            [phi0_of_alpha(alpha) / alpha]
        });
        ModelTable {
            forward,
            inverse,
            max_tau,
            max_alpha,
        }
    }

    /// The table every part of the process shares, built on first use.
    pub fn global() -> &'static ModelTable {
        static TABLE: OnceLock<ModelTable> = OnceLock::new();
        TABLE.get_or_init(ModelTable::build)
    }

    /// The largest load in the table, alpha(89 deg).
    pub fn max_alpha(&self) -> f64 {
        self.max_alpha
    }

    /// The elastica for a tip slope in radians (|phi0| <= 89 deg, else saturated).
    #[inline]
    pub fn elastica_rad(&self, phi0_rad: f64) -> Lookup<Elastica> {
        let (magnitude, saturated) = clamp_magnitude(phi0_rad, MAX_PHI0_RAD);
        // min: rounding in tau_of must not step past the last piece's end.
        let [a, d, s] = self.forward.eval(tau_of(magnitude).min(self.max_tau));
        Lookup {
            value: Elastica {
                alpha: (a * magnitude).copysign(phi0_rad),
                delta_over_l: (d * magnitude).copysign(phi0_rad),
                shortening_over_l: s * magnitude * magnitude,
            },
            saturated,
        }
    }

    /// The elastica for a tip angle in degrees (|angle| <= 89, else saturated).
    #[inline]
    pub fn elastica_deg(&self, angle_deg: f64) -> Lookup<Elastica> {
        self.elastica_rad(angle_deg.to_radians())
    }

    /// The nondimensional load alpha = F L^2 / EI for a tip slope in radians.
    #[inline]
    pub fn alpha_rad(&self, phi0_rad: f64) -> Lookup<f64> {
        self.elastica_rad(phi0_rad).map(|e| e.alpha)
    }

    /// The nondimensional load alpha = F L^2 / EI for a tip angle in degrees.
    #[inline]
    pub fn alpha_deg(&self, angle_deg: f64) -> Lookup<f64> {
        self.alpha_rad(angle_deg.to_radians())
    }

    /// The tip slope (radians, sign of alpha) that carries the load `alpha`
    /// (|alpha| <= [`ModelTable::max_alpha`], else saturated at 89 deg).
    #[inline]
    pub fn phi0_rad_from_alpha(&self, alpha: f64) -> Lookup<f64> {
        let (magnitude, saturated) = clamp_magnitude(alpha, self.max_alpha);
        let [ratio] = self.inverse.eval(magnitude.sqrt());
        // Not f64::min, which would turn a NaN request into 89 deg.
        let phi0 = ratio * magnitude;
        let phi0 = if phi0 > MAX_PHI0_RAD {
            MAX_PHI0_RAD
        } else {
            phi0
        };
        Lookup {
            value: phi0.copysign(alpha),
            saturated,
        }
    }

    /// The tip angle in degrees that carries the load `alpha`.
    #[inline]
    pub fn angle_deg_from_alpha(&self, alpha: f64) -> Lookup<f64> {
        self.phi0_rad_from_alpha(alpha).map(f64::to_degrees)
    }
}

/// |x| limited to `max`, and whether it had to be; NaN stays NaN and counts as saturated.
#[inline]
fn clamp_magnitude(x: f64, max: f64) -> (f64, bool) {
    let magnitude = x.abs();
    if magnitude <= max {
        (magnitude, false)
    } else if x.is_nan() {
        (f64::NAN, true)
    } else {
        (max, true)
    }
}
