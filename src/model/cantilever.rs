//! Cantilever stiffness: flexural rigidity EI from a spring constant or a cross-section,
//! the force scale EI / L^2 that turns the nondimensional load alpha into newtons, and
//! the tip force for a tip angle (and back) through the shared [`ModelTable`].

use super::table::{Lookup, ModelTable};

/// A cantilever's length and flexural rigidity, as validated from `[cantilever]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cantilever {
    pub length_um: f64,
    /// E * I in N m^2.
    pub flexural_rigidity_n_m2: f64,
}

impl Cantilever {
    pub fn new(length_um: f64, flexural_rigidity_n_m2: f64) -> Self {
        Cantilever {
            length_um,
            flexural_rigidity_n_m2,
        }
    }

    /// EI = k L^3 / 3 (small-deflection tip stiffness of an end-loaded cantilever).
    pub fn rigidity_from_spring_constant(spring_constant_n_per_m: f64, length_um: f64) -> f64 {
        let length_m = length_um * 1e-6;
        spring_constant_n_per_m * length_m * length_m * length_m / 3.0
    }

    /// EI = E w t^3 / 12 for a rectangular section.
    pub fn rigidity_from_section(youngs_modulus_gpa: f64, width_um: f64, thickness_um: f64) -> f64 {
        let thickness_m = thickness_um * 1e-6;
        youngs_modulus_gpa * 1e9 * width_um * 1e-6 * thickness_m * thickness_m * thickness_m / 12.0
    }

    /// EI / L^2 in nanonewtons: the tip force for a nondimensional load alpha = 1.
    pub fn force_scale_nn(&self) -> f64 {
        let length_m = self.length_um * 1e-6;
        self.flexural_rigidity_n_m2 / (length_m * length_m) * 1e9
    }

    /// The tip force in nN for a tip angle in degrees: alpha(|angle|) EI / L^2 with the
    /// sign of the angle, through [`ModelTable::global`]. Beyond +-89 deg the force is
    /// the one at +-89 deg and `saturated` is set; NaN gives NaN, saturated.
    pub fn force_nn(&self, angle_deg: f64) -> Lookup<f64> {
        let scale_nn = self.force_scale_nn();
        ModelTable::global()
            .alpha_deg(angle_deg)
            .map(|alpha| alpha * scale_nn)
    }

    /// The tip angle in degrees (sign of the force) at which the tip carries `force_nn`,
    /// through [`ModelTable::global`]; saturated at +-89 deg beyond the table's range.
    pub fn angle_from_force_nn(&self, force_nn: f64) -> Lookup<f64> {
        ModelTable::global().angle_deg_from_alpha(force_nn / self.force_scale_nn())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spring_constant_and_force_scale() {
        // Public sample `mixed`: L = 434.675 um, k = 0.06 N/m -> EI / L^2 = k L / 3.
        let ei = Cantilever::rigidity_from_spring_constant(0.06, 434.675);
        let c = Cantilever::new(434.675, ei);
        let expected_nn = 0.06 * 434.675e-6 / 3.0 * 1e9;
        assert!((c.force_scale_nn() / expected_nn - 1.0).abs() < 1e-14);
    }

    #[test]
    fn force_follows_the_exact_model_with_the_sign_of_the_angle() {
        let c = Cantilever::new(
            434.675,
            Cantilever::rigidity_from_spring_constant(0.06, 434.675),
        );
        for angle_deg in [-20.0, -5.0, 0.01, 1.0, 12.5, 45.0, 89.0] {
            let want = crate::model::exact(f64::to_radians(angle_deg))
                .unwrap()
                .alpha;
            let got = c.force_nn(angle_deg);
            assert!(!got.saturated);
            let rel = got.value / (want * c.force_scale_nn()) - 1.0;
            assert!(rel.abs() < 1e-12, "{angle_deg} deg: relative error {rel:e}");
            let back = c.angle_from_force_nn(got.value);
            assert!(!back.saturated);
            assert!(
                (back.value / angle_deg - 1.0).abs() < 1e-12,
                "{angle_deg}: {back:?}"
            );
        }
        assert_eq!(c.force_nn(0.0).value, 0.0);
    }

    #[test]
    fn force_saturates_beyond_89_degrees() {
        let c = Cantilever::new(400.0, 1e-12);
        let limit = c.force_nn(89.0);
        let beyond = c.force_nn(-120.0);
        assert!(beyond.saturated && !limit.saturated);
        assert_eq!(beyond.value, -limit.value);
        let back = c.angle_from_force_nn(10.0 * limit.value);
        assert!(back.saturated);
        assert!((back.value - 89.0).abs() < 1e-12, "{back:?}");
        let nan = c.force_nn(f64::NAN);
        assert!(nan.saturated && nan.value.is_nan());
    }

    #[test]
    fn cross_section() {
        let ei = Cantilever::rigidity_from_section(169.0, 40.0, 2.0);
        assert!((ei / (169e9 * 40e-6 * 8e-18 / 12.0) - 1.0).abs() < 1e-14);
    }
}
