//! The simulated lab of a configuration's `[sim]` sections, device by device: the S100
//! behind the DAQ trait, the SEM that renders the probe as the stage bends it, and the
//! scripted operator's stylus. Whoever opens the lab (the daemon) picks, per device,
//! these or the real backend `hw::open` opens.
use super::config::{SimConfig, SimProbe};
use super::contact::Contact;
use super::daq::{SimStage, StageSnapshot};
use super::haptic::SimHaptic;
use super::operator::{HandModel, Operator};
use super::sem::{ProbeView, SemScene};
use crate::control::TeleopGains;
use crate::model::Cantilever;
use crate::scene::Entry;

/// A probe's simulated S100 positioner, at rest at its start, and the reading end of
/// its state for the simulated SEM.
pub fn stage(
    sim: &SimConfig,
    probe: &SimProbe,
    teleop: &TeleopGains,
) -> (SimStage, triple_buffer::Output<StageSnapshot>) {
    SimStage::new(
        sim.stage.clone(),
        teleop.press_direction_stage * probe.start_um,
    )
}

/// The simulated SEM's view of `probes` (each a cantilever and its place, in order),
/// each pressing on `[sim.sample]` along the teleoperation's press direction, imaged as
/// `[sim.sem]` says. A probe entering from the right is the mirror image of one from
/// the left: pressing bends it the other way on screen.
pub fn sem_scene(
    sim: &SimConfig,
    probes: &[(Cantilever, SimProbe)],
    teleop: &TeleopGains,
) -> SemScene {
    let views = probes
        .iter()
        .map(|(cantilever, place)| {
            let contact = Contact {
                sample: sim.sample.clone(),
                cantilever: *cantilever,
                press_direction: teleop.press_direction_stage,
            };
            let mirrored = match place.entry {
                Entry::Left => 1.0,
                Entry::Right => -1.0,
            };
            let sign = teleop.pressing_force_sign * mirrored;
            ProbeView::new(&sim.sem, contact, sign, place.clone())
        })
        .collect();
    SemScene::several(sim.sem.clone(), views)
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
