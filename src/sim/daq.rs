//! The `"sim"` DAQ backend: rate commands move the simulated S100 ([`super::stage`]).
//! Each command also publishes the stage's state for the simulated SEM, through a
//! latest-only slot (the SEM never holds up the haptic loop).
use nalgebra::Vector3;

use super::stage::{Stage, StageParams};
use crate::hw::daq::{DaqError, RateOutput};

/// The stage as the simulated SEM sees it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageSnapshot {
    pub t_s: f64,
    pub position_um: Vector3<f64>,
    pub velocity_um_s: Vector3<f64>,
}

impl StageSnapshot {
    /// The position at a nearby time, extrapolated with the current velocity.
    pub fn position_at(&self, t_s: f64) -> Vector3<f64> {
        self.position_um + self.velocity_um_s * (t_s - self.t_s)
    }
}

pub struct SimStage {
    stage: Stage,
    snapshots: triple_buffer::Input<StageSnapshot>,
}

impl SimStage {
    /// The stage, at rest at `start_um`, and the reading end of its state for the SEM.
    pub fn new(
        params: StageParams,
        start_um: Vector3<f64>,
    ) -> (SimStage, triple_buffer::Output<StageSnapshot>) {
        let (snapshots, output) = triple_buffer::triple_buffer(&StageSnapshot {
            position_um: start_um,
            ..StageSnapshot::default()
        });
        (
            SimStage {
                stage: Stage::starting_at(params, start_um),
                snapshots,
            },
            output,
        )
    }
}

impl RateOutput for SimStage {
    fn name(&self) -> &str {
        "sim:S100"
    }

    fn write_velocity(&mut self, now_s: f64, velocity_um_s: Vector3<f64>) -> Result<(), DaqError> {
        self.stage.command(now_s, velocity_um_s);
        self.snapshots.write(StageSnapshot {
            t_s: now_s,
            position_um: self.stage.position_um(),
            velocity_um_s: self.stage.velocity_um_s(),
        });
        Ok(())
    }
}
