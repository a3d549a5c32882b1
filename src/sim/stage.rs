//! The simulated S100 positioner: velocity-commanded, with a speed limit, a first-order
//! lag, a finite resolution and a bounded workspace.
use nalgebra::Vector3;

/// Parameters of the simulated positioner (`[sim.stage]`).
#[derive(Debug, Clone, PartialEq)]
pub struct StageParams {
    pub speed_limit_um_per_s: f64,
    /// Time constant of the velocity response.
    pub lag_ms: f64,
    /// Positions are reported in steps of this size (the S100's +-5 nm).
    pub resolution_nm: f64,
    /// Edge length of the cubic workspace, centred on the start position.
    pub workspace_mm: f64,
}

impl Default for StageParams {
    fn default() -> Self {
        StageParams {
            speed_limit_um_per_s: 100.0,
            lag_ms: 15.0,
            resolution_nm: 5.0,
            workspace_mm: 12.0,
        }
    }
}

/// The positioner's state, advanced in time by each command.
#[derive(Debug, Clone)]
pub struct Stage {
    params: StageParams,
    position_um: Vector3<f64>,
    velocity_um_s: Vector3<f64>,
    command_um_s: Vector3<f64>,
    last_s: Option<f64>,
}

impl Stage {
    pub fn new(params: StageParams) -> Self {
        Stage::starting_at(params, Vector3::zeros())
    }

    /// A stage at rest at `position_um`.
    pub fn starting_at(params: StageParams, position_um: Vector3<f64>) -> Self {
        Stage {
            params,
            position_um,
            velocity_um_s: Vector3::zeros(),
            command_um_s: Vector3::zeros(),
            last_s: None,
        }
    }

    /// A new velocity command at `now_s`; the motion until then follows the previous one.
    pub fn command(&mut self, now_s: f64, velocity_um_s: Vector3<f64>) {
        self.advance(now_s);
        let limit = self.params.speed_limit_um_per_s;
        let speed = velocity_um_s.norm();
        self.command_um_s = if speed > limit && speed > 0.0 {
            velocity_um_s * (limit / speed)
        } else if speed.is_finite() {
            velocity_um_s
        } else {
            Vector3::zeros()
        };
    }

    /// Integrates up to `now_s` (exact for a first-order lag under a constant command).
    pub fn advance(&mut self, now_s: f64) {
        let dt = match self.last_s {
            Some(last) if now_s > last => now_s - last,
            Some(_) => return,
            None => {
                self.last_s = Some(now_s);
                return;
            }
        };
        self.last_s = Some(now_s);
        let tau = (self.params.lag_ms * 1e-3).max(1e-6);
        let decay = (-dt / tau).exp();
        let v0 = self.velocity_um_s;
        let target = self.command_um_s;
        // x(t) = x0 + c t + (v0 - c) tau (1 - e^{-t/tau})
        self.position_um += target * dt + (v0 - target) * tau * (1.0 - decay);
        self.velocity_um_s = target + (v0 - target) * decay;
        let half = self.params.workspace_mm * 500.0;
        for axis in 0..3 {
            if self.position_um[axis].abs() > half {
                self.position_um[axis] = self.position_um[axis].clamp(-half, half);
                self.velocity_um_s[axis] = 0.0;
            }
        }
    }

    /// The position as the positioner resolves it.
    pub fn position_um(&self) -> Vector3<f64> {
        let step_um = self.params.resolution_nm * 1e-3;
        if step_um > 0.0 {
            self.position_um.map(|p| (p / step_um).round() * step_um)
        } else {
            self.position_um
        }
    }

    pub fn velocity_um_s(&self) -> Vector3<f64> {
        self.velocity_um_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lag_speed_limit_and_resolution() {
        let mut stage = Stage::new(StageParams::default());
        stage.command(0.0, Vector3::new(10.0, 0.0, 0.0));
        stage.advance(0.015);
        // One time constant: 63 % of the commanded speed.
        assert!((stage.velocity_um_s().x - 10.0 * (1.0 - (-1.0f64).exp())).abs() < 1e-9);
        stage.advance(2.0);
        // After the transient: x = c t - c tau.
        assert!((stage.position_um().x - (20.0 - 0.15)).abs() < 0.006);
        let p = stage.position_um().x / 0.005;
        assert!((p - p.round()).abs() < 1e-6, "5 nm steps");
        stage.command(2.0, Vector3::new(0.0, 1000.0, 0.0));
        stage.advance(3.0);
        assert!(
            (stage.velocity_um_s().y - 100.0).abs() < 1e-6,
            "speed limit"
        );
    }

    #[test]
    fn workspace_is_bounded() {
        let mut stage = Stage::new(StageParams::default());
        stage.command(0.0, Vector3::new(0.0, 0.0, -100.0));
        stage.advance(100.0);
        assert_eq!(stage.position_um().z, -6000.0);
        assert_eq!(stage.velocity_um_s().z, 0.0);
    }

    #[test]
    fn non_finite_commands_stop_the_stage() {
        let mut stage = Stage::new(StageParams::default());
        stage.command(0.0, Vector3::new(f64::NAN, 0.0, 0.0));
        stage.advance(1.0);
        assert_eq!(stage.position_um(), Vector3::zeros());
    }
}
