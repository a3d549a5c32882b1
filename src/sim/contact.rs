//! The simulated contact between the cantilever tip and the sample: when the stage
//! carries the clamp past the point of contact, the beam bends and the sample yields,
//! in series. The tip slope and the true contact force come from the exact elastica
//! (root-finding on [`crate::model::exact`]), independently of the lookup table the
//! tracker uses, so the simulator checks the table rather than agreeing with it.
use nalgebra::Vector3;

use crate::model::{exact, Cantilever, MAX_PHI0_RAD};

/// Where the sample is and how it yields (`[sim.sample]`).
#[derive(Debug, Clone, PartialEq)]
pub struct SampleParams {
    /// Travel of the stage along the press direction, from its start, to first contact.
    pub contact_at_um: f64,
    /// Contact stiffness of the sample surface.
    pub stiffness_n_per_m: f64,
}

impl Default for SampleParams {
    fn default() -> Self {
        SampleParams {
            contact_at_um: 20.0,
            stiffness_n_per_m: 20.0,
        }
    }
}

/// The beam's state for one stage position.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Bending {
    /// Tip slope, radians, >= 0 (the sign on screen is the caller's convention).
    pub phi0_rad: f64,
    /// Contact force, nN, >= 0.
    pub force_nn: f64,
    /// How far past first contact the clamp is, um (0 when free).
    pub overtravel_um: f64,
    /// True when the overtravel exceeds what the model covers (89 deg): clamped there.
    pub saturated: bool,
}

#[derive(Debug, Clone)]
pub struct Contact {
    pub sample: SampleParams,
    pub cantilever: Cantilever,
    /// Unit vector, stage frame: moving this way presses the tip on the sample.
    pub press_direction: Vector3<f64>,
}

impl Contact {
    /// The exact bending for a stage position.
    pub fn bending(&self, stage_position_um: Vector3<f64>) -> Bending {
        let overtravel_um =
            stage_position_um.dot(&self.press_direction) - self.sample.contact_at_um;
        if overtravel_um.is_nan() || overtravel_um <= 0.0 {
            return Bending::default();
        }
        let residual = |phi0: f64| self.travel_um(phi0) - overtravel_um;
        if residual(MAX_PHI0_RAD) <= 0.0 {
            return Bending {
                phi0_rad: MAX_PHI0_RAD,
                force_nn: self.force_nn(MAX_PHI0_RAD),
                overtravel_um,
                saturated: true,
            };
        }
        let phi0_rad = bisect(residual, 0.0, MAX_PHI0_RAD);
        Bending {
            phi0_rad,
            force_nn: self.force_nn(phi0_rad),
            overtravel_um,
            saturated: false,
        }
    }

    /// Tip deflection plus sample indentation at a tip slope, um: the overtravel that
    /// produces that slope.
    fn travel_um(&self, phi0_rad: f64) -> f64 {
        let Ok(e) = exact(phi0_rad) else {
            return f64::INFINITY;
        };
        let deflection_um = e.delta_over_l * self.cantilever.length_um;
        let indentation_um = self.force_nn(phi0_rad) * 1e-9 / self.sample.stiffness_n_per_m * 1e6;
        deflection_um + indentation_um
    }

    fn force_nn(&self, phi0_rad: f64) -> f64 {
        exact(phi0_rad).map_or(f64::NAN, |e| e.alpha * self.cantilever.force_scale_nn())
    }
}

/// Root of an increasing function on [lo, hi] with f(lo) <= 0 < f(hi), to the last bit.
fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if f(mid) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contact() -> Contact {
        let ei = Cantilever::rigidity_from_spring_constant(0.06, 434.675);
        Contact {
            sample: SampleParams {
                contact_at_um: 10.0,
                stiffness_n_per_m: 5.0,
            },
            cantilever: Cantilever::new(434.675, ei),
            press_direction: Vector3::new(0.0, 0.0, -1.0),
        }
    }

    #[test]
    fn free_until_contact() {
        let c = contact();
        assert_eq!(c.bending(Vector3::new(0.0, 0.0, -9.9)), Bending::default());
        assert_eq!(c.bending(Vector3::new(50.0, 0.0, 3.0)), Bending::default());
    }

    #[test]
    fn bending_satisfies_the_series_springs_exactly() {
        let c = contact();
        for overtravel in [0.001, 0.5, 5.0, 30.0, 60.0, 150.0] {
            let b = c.bending(Vector3::new(0.0, 0.0, -10.0 - overtravel));
            let e = exact(b.phi0_rad).unwrap();
            let deflection_um = e.delta_over_l * 434.675;
            let force_nn = e.alpha * c.cantilever.force_scale_nn();
            assert!((b.force_nn - force_nn).abs() <= 1e-9 * force_nn);
            let indentation_um = force_nn * 1e-9 / 5.0 * 1e6;
            let total = deflection_um + indentation_um;
            assert!(
                (total - overtravel).abs() < 1e-9 * overtravel.max(1.0),
                "{total} vs {overtravel}"
            );
            assert!(!b.saturated);
        }
    }

    #[test]
    fn small_overtravel_follows_the_linear_spring() {
        // Cantilever (0.06 N/m) and sample (5 N/m) in series, small deflection.
        let c = contact();
        let b = c.bending(Vector3::new(0.0, 0.0, -10.01));
        let k_series = 1.0 / (1.0 / 0.06 + 1.0 / 5.0);
        let expected_nn = k_series * 0.01e-6 * 1e9;
        assert!(
            (b.force_nn / expected_nn - 1.0).abs() < 1e-4,
            "{} vs {expected_nn}",
            b.force_nn
        );
    }

    #[test]
    fn saturates_beyond_the_model() {
        let b = contact().bending(Vector3::new(0.0, 0.0, -10_000.0));
        assert!(b.saturated);
        assert_eq!(b.phi0_rad, MAX_PHI0_RAD);
    }
}
