//! The lookup table the paper calls for: built once at start-up from the exact elastica,
//! then angle -> (alpha, delta/L, Delta/L) and load -> angle in a few dozen nanoseconds,
//! with a relative error of ~1e-14 over the whole range (the tests require 1e-12 at 120k
//! points; the budget is 1e-9).
//!
//! Design (docs/model.md has the measurements):
//! - Forward, the variable is pi/2 - phi0, on a geometric mesh (four pieces per octave,
//!   from 2^-6 to 2): alpha has a logarithmic singularity at 90 deg and every piece is at
//!   least four widths away from it, so each converges alike. The piece is read off the
//!   float's bits ([`super::chebyshev::Octaves`]), so a lookup takes no logarithm.
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

use super::chebyshev::{Octaves, Uniform};
use super::elastica::{alpha_of, elastica_of, Elastica, MAX_PHI0_RAD};
use super::inverse::{max_alpha, phi0_of_alpha, solve_increasing};

/// Pieces of the inverse interpolant; with degree 12 it is exact to rounding (~3e-15).
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
    /// [alpha/phi0, delta/(L phi0), Delta/(L phi0^2)] against pi/2 - phi0.
    forward: Octaves<3>,
    /// phi0/alpha against sqrt(alpha).
    inverse: Uniform<1>,
    max_alpha: f64,
}

impl ModelTable {
    /// Samples the exact model (676 closed-form evaluations; see `phi0_for_node`).
    pub fn build() -> ModelTable {
        let forward = Octaves::build(FRAC_PI_2 - MAX_PHI0_RAD, FRAC_PI_2, |distance| {
            forward_ratios(FRAC_PI_2 - distance)
        });
        // The exact load at 89 deg, or the forward table's if rounding made that larger, so
        // that any load the table returns maps back without saturating.
        let at_limit = forward.eval(FRAC_PI_2 - MAX_PHI0_RAD)[0] * MAX_PHI0_RAD;
        let max_alpha = max_alpha().max(at_limit);
        let inverse = Uniform::build(0.0, max_alpha.sqrt(), INVERSE_PIECES, |w| {
            let alpha = w * w;
            [phi0_for_node(&forward, alpha) / alpha]
        });
        ModelTable {
            forward,
            inverse,
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
        let [a, d, s] = self.forward.eval(FRAC_PI_2 - magnitude);
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

/// The exact phi0 carrying the load `alpha` (0 < alpha <= alpha(89 deg)), found fast: a
/// root of the forward interpolant (good to ~1e-14, at ~20 ns an evaluation) polished
/// by one Newton step on the exact model, whose slope it takes from the interpolant.
/// Five times faster than root-finding on the exact model alone, and as accurate.
fn phi0_for_node(forward: &Octaves<3>, alpha: f64) -> f64 {
    let table_alpha = |p: f64| forward.eval(FRAC_PI_2 - p)[0] * p;
    let guess = solve_increasing(|p| table_alpha(p) - alpha, 0.0, MAX_PHI0_RAD);
    let step = 1e-6 * guess;
    let slope = (table_alpha(guess + step) - table_alpha(guess - step)) / (2.0 * step);
    let polished = guess - (alpha_of(guess) - alpha) / slope;
    if (polished - guess).abs() <= 1e-12 * guess {
        polished
    } else {
        // The interpolant was off by more than it can be: trust only the exact model.
        phi0_of_alpha(alpha)
    }
}

/// [alpha/phi0, delta/(L phi0), Delta/(L phi0^2)]: even in phi0 and analytic through 0
/// (the forward mesh samples a little below 0), with their limits 2, 2/3, 4/15 at 0.
fn forward_ratios(phi0_rad: f64) -> [f64; 3] {
    let magnitude = phi0_rad.abs();
    if magnitude == 0.0 {
        return [2.0, 2.0 / 3.0, 4.0 / 15.0];
    }
    let e = elastica_of(magnitude);
    [
        e.alpha / magnitude,
        e.delta_over_l / magnitude,
        e.shortening_over_l / (magnitude * magnitude),
    ]
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::reference::SplitMix;
    use crate::model::{exact, phi0_from_alpha, MAX_PHI0_DEG};
    use proptest::prelude::*;
    use std::time::{Duration, Instant};

    fn rel(got: f64, want: f64) -> f64 {
        if want == 0.0 {
            got.abs()
        } else {
            (got / want - 1.0).abs()
        }
    }

    /// 120k slopes: uniform over (0, 89] deg, log-uniform down to 1e-9 deg, and within
    /// 1e-3 deg of the 89 deg limit, plus the ends themselves.
    fn dense_slopes_rad() -> Vec<f64> {
        let mut rng = SplitMix(0x7AB1E);
        let mut deg: Vec<f64> = Vec::with_capacity(120_004);
        deg.extend((0..80_000).map(|_| MAX_PHI0_DEG * (1.0 - rng.next_f64())));
        deg.extend((0..20_000).map(|_| 10f64.powf(-9.0 + 9.0 * rng.next_f64())));
        deg.extend((0..20_000).map(|_| MAX_PHI0_DEG - 1e-3 * rng.next_f64()));
        deg.extend([1e-300, 5e-324, MAX_PHI0_DEG, 45.0]);
        deg.into_iter().map(f64::to_radians).collect()
    }

    #[test]
    fn forward_lookup_matches_the_exact_model_densely() {
        let table = ModelTable::build();
        let mut worst = [(0.0, 0.0); 3];
        for phi0 in dense_slopes_rad() {
            let want = exact(phi0).unwrap();
            let got = table.elastica_rad(phi0);
            assert!(!got.saturated, "{phi0}");
            let pairs = [
                (got.value.alpha, want.alpha),
                (got.value.delta_over_l, want.delta_over_l),
                (got.value.shortening_over_l, want.shortening_over_l),
            ];
            for (m, (g, w)) in pairs.into_iter().enumerate() {
                // Below ~1e-160 rad Delta/L = 4 phi0^2/15 is subnormal or zero.
                if w.abs() < 1e-290 {
                    assert!(g.abs() <= 1e-290);
                    continue;
                }
                if rel(g, w) > worst[m].0 {
                    worst[m] = (rel(g, w), phi0.to_degrees());
                }
            }
        }
        eprintln!("table vs exact, 120k slopes: worst (relative error, angle_deg) {worst:?}");
        for (err, deg) in worst {
            assert!(
                err < 1e-12,
                "relative error {err:e} at {deg} deg (budget 1e-9)"
            );
        }
    }

    #[test]
    fn inverse_lookup_matches_the_exact_model_densely() {
        let table = ModelTable::build();
        let mut worst = (0.0, 0.0);
        for phi0 in dense_slopes_rad() {
            let alpha = exact(phi0).unwrap().alpha;
            let got = table.phi0_rad_from_alpha(alpha);
            assert!(!got.saturated, "{alpha}");
            if rel(got.value, phi0) > worst.0 {
                worst = (rel(got.value, phi0), phi0.to_degrees());
            }
        }
        // And uniformly in the load, against the exact root-finder.
        let mut rng = SplitMix(0x1F0ACE);
        for _ in 0..20_000 {
            let alpha = table.max_alpha() * rng.next_f64();
            let want = phi0_from_alpha(alpha).unwrap();
            let got = table.phi0_rad_from_alpha(alpha).value;
            if rel(got, want) > worst.0 {
                worst = (rel(got, want), want.to_degrees());
            }
        }
        eprintln!("table inverse vs exact: worst (relative error, angle_deg) {worst:?}");
        assert!(
            worst.0 < 1e-12,
            "relative error {:e} at {} deg",
            worst.0,
            worst.1
        );
    }

    #[test]
    fn lookups_saturate_outside_the_range_and_say_so() {
        let table = ModelTable::global();
        let limit = table.elastica_deg(MAX_PHI0_DEG);
        assert!(!limit.saturated);
        let beyond = table.elastica_deg(-89.5);
        assert!(beyond.saturated);
        assert_eq!(beyond.value.alpha, -limit.value.alpha);
        assert_eq!(
            beyond.value.shortening_over_l,
            limit.value.shortening_over_l
        );
        assert!(table.elastica_deg(f64::INFINITY).saturated);
        let nan = table.elastica_deg(f64::NAN);
        assert!(nan.saturated && nan.value.alpha.is_nan() && nan.value.delta_over_l.is_nan());

        let top = table.angle_deg_from_alpha(table.max_alpha());
        assert!(
            !top.saturated && (top.value - MAX_PHI0_DEG).abs() < 1e-12,
            "{top:?}"
        );
        let over = table.angle_deg_from_alpha(-1e6);
        assert!(over.saturated && over.value == -MAX_PHI0_DEG, "{over:?}");
        let nan = table.angle_deg_from_alpha(f64::NAN);
        assert!(nan.saturated && nan.value.is_nan());
        assert_eq!(table.angle_deg_from_alpha(0.0).value, 0.0);
        assert_eq!(table.alpha_deg(0.0).value, 0.0);
    }

    #[test]
    fn forward_ratios_are_continuous_through_zero() {
        let [a, d, s] = forward_ratios(1e-9);
        assert_eq!(forward_ratios(-1e-9), [a, d, s]);
        let limit = forward_ratios(0.0);
        assert!((a - limit[0]).abs() < 1e-15 && (d - limit[1]).abs() < 1e-15);
        assert!((s - limit[2]).abs() < 1e-15);
    }

    #[test]
    fn global_table_is_shared() {
        assert!(std::ptr::eq(ModelTable::global(), ModelTable::global()));
    }

    /// The start-up budget is 5 ms; the bench measures ~0.3 ms in release.
    #[test]
    fn builds_within_the_start_up_budget() {
        let budget = if cfg!(debug_assertions) {
            Duration::from_millis(50)
        } else {
            Duration::from_millis(5)
        };
        let fastest = (0..5)
            .map(|_| {
                let start = Instant::now();
                std::hint::black_box(ModelTable::build());
                start.elapsed()
            })
            .min()
            .unwrap_or_default();
        assert!(fastest < budget, "table build took {fastest:?}");
    }

    proptest! {
        #[test]
        fn lookups_are_symmetric_and_match_exact(angle_deg in -MAX_PHI0_DEG..=MAX_PHI0_DEG) {
            let table = ModelTable::global();
            let (plus, minus) = (table.elastica_deg(angle_deg), table.elastica_deg(-angle_deg));
            prop_assert_eq!(minus.value.alpha, -plus.value.alpha);
            prop_assert_eq!(minus.value.delta_over_l, -plus.value.delta_over_l);
            prop_assert_eq!(minus.value.shortening_over_l, plus.value.shortening_over_l);
            let want = exact(angle_deg.to_radians()).unwrap();
            prop_assert!(rel(plus.value.alpha, want.alpha) < 1e-12);
            let back = table.angle_deg_from_alpha(plus.value.alpha);
            prop_assert!(!back.saturated);
            prop_assert!((back.value - angle_deg).abs() <= 1e-12 * angle_deg.abs());
            prop_assert_eq!(table.angle_deg_from_alpha(-plus.value.alpha).value, -back.value);
        }
    }
}
