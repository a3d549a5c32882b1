//! The `"sim"` haptic backend: the stylus held by the scripted virtual operator
//! ([`super::operator`]), who feels the forces the daemon renders.
use nalgebra::Vector3;

use super::operator::Operator;
use crate::hw::haptic::{HapticDevice, HapticError, HapticSample};

pub struct SimHaptic {
    operator: Operator,
    forces_enabled: bool,
    force_n: Vector3<f64>,
}

impl SimHaptic {
    pub fn new(operator: Operator) -> Self {
        SimHaptic {
            operator,
            forces_enabled: false,
            force_n: Vector3::zeros(),
        }
    }
}

impl HapticDevice for SimHaptic {
    fn name(&self) -> &str {
        "sim:PHANToM"
    }

    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError> {
        self.operator.advance(now_s);
        Ok(HapticSample {
            position_mm: self.operator.position_mm(),
            velocity_mm_s: self.operator.velocity_mm_s(),
            buttons: 0,
        })
    }

    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError> {
        self.force_n = force_n;
        self.operator.feel(if self.forces_enabled {
            force_n
        } else {
            Vector3::zeros()
        });
        Ok(())
    }

    fn set_forces_enabled(&mut self, enabled: bool) -> Result<(), HapticError> {
        self.forces_enabled = enabled;
        self.operator.feel(if enabled {
            self.force_n
        } else {
            Vector3::zeros()
        });
        Ok(())
    }
}
