//! The simulated lab of a configuration's `[sim]` sections, device by device: the S100
//! behind the DAQ trait, the SEM that renders the probe as the stage bends it, and the
//! scripted operator's stylus. Whoever opens the lab (the daemon) picks, per device,
//! these or the real backend `hw::open` opens.
use super::config::SimConfig;
use super::contact::Contact;
use super::daq::{SimStage, StageSnapshot};
use super::haptic::SimHaptic;
use super::operator::{HandModel, Operator};
use super::sem::SemScene;
use crate::control::TeleopGains;
use crate::model::Cantilever;

/// The simulated S100 and the reading end of its state for the simulated SEM.
pub fn stage(sim: &SimConfig) -> (SimStage, triple_buffer::Output<StageSnapshot>) {
    SimStage::new(sim.stage.clone())
}

/// The simulated SEM: `cantilever` pressing on `[sim.sample]` along the teleoperation's
/// press direction, imaged as `[sim.sem]` says.
pub fn sem_scene(sim: &SimConfig, cantilever: Cantilever, teleop: &TeleopGains) -> SemScene {
    let contact = Contact {
        sample: sim.sample.clone(),
        cantilever,
        press_direction: teleop.press_direction_stage,
    };
    SemScene::new(sim.sem.clone(), contact, teleop.pressing_force_sign)
}

/// The stylus held by the scripted operator of `[sim.operator]`, whose hand follows the
/// teleoperation's axes, centring spring and force scale.
pub fn haptic(sim: &SimConfig, teleop: &TeleopGains) -> SimHaptic {
    let hand = HandModel {
        press_direction_haptic: teleop.haptic_from_stage() * teleop.press_direction_stage,
        spring_n_per_mm: teleop.spring_n_per_mm,
        force_scale_n_per_nn: teleop.force_scale_n_per_nn,
    };
    SimHaptic::new(Operator::new(sim.operator.clone(), hand))
}
