//! Cantilever stiffness: flexural rigidity EI from a spring constant or a cross-section,
//! and the force scale EI / L^2 that turns the nondimensional load alpha into newtons.

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
    fn cross_section() {
        let ei = Cantilever::rigidity_from_section(169.0, 40.0, 2.0);
        assert!((ei / (169e9 * 40e-6 * 8e-18 / 12.0) - 1.0).abs() < 1e-14);
    }
}
