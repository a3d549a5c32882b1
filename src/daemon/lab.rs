//! Opening the lab a configuration describes: each device from its backend, and the
//! tracker calibrated on its reference frame. With the simulated SEM the reference frame
//! and the clicks come from the simulator; otherwise from `[tracker.calibration]`.
use anyhow::Context;
use image::GrayImage;

use super::{Devices, Estimator, FrameEstimate};
use crate::config::{CalibrationConfig, Config};
use crate::hw::daq::sim::SimStage;
use crate::hw::frames::sim::SimSem;
use crate::hw::haptic::sim::SimHaptic;
use crate::hw::Clock;
use crate::session::frames::load_gray;
use crate::sim::contact::Contact;
use crate::sim::operator::{HandModel, Operator};
use crate::sim::sem::SemScene;
use crate::vision::{Calibration, Estimate, Tracker};

/// The vision tracker as the daemon's estimator.
pub struct VisionEstimator(pub Tracker);

impl Estimator for VisionEstimator {
    fn estimate(&mut self, frame: &GrayImage) -> FrameEstimate {
        from_estimate(&self.0.track(frame))
    }
}

/// A tracker estimate as the daemon publishes it. A force clamped at the model's limit
/// is not a measurement: such a frame is not a detection the operator may feel.
pub fn from_estimate(e: &Estimate) -> FrameEstimate {
    let detected = e.detected && e.force_nn.is_some() && !e.force_saturated;
    FrameEstimate {
        detected,
        angle_deg: e.angle_deg.filter(|_| detected),
        force_nn: e.force_nn.filter(|_| detected),
        apex_px: e.apex_px.filter(|_| detected),
        confidence: e.confidence,
    }
}

/// Opens every device of `config` (all `"sim"` today; the hardware backends plug in
/// here) and calibrates the tracker. Fails with a message naming the device.
pub fn open(config: &Config, clock: Clock) -> anyhow::Result<Devices> {
    let teleop = &config.teleop;
    let (stage, snapshots) = SimStage::new(config.sim.stage.clone());
    let contact = Contact {
        sample: config.sim.sample.clone(),
        cantilever: config.cantilever,
        press_direction: teleop.press_direction_stage,
    };
    let scene = SemScene::new(config.sim.sem.clone(), contact, teleop.pressing_force_sign);
    let (reference, clicks) = scene.reference(config.tracker.threshold, config.tracker.window_deg);
    let calibration = calibrate(config, &reference, &clicks)?;
    let tracker = Tracker::new(&config.tracker, calibration, Some(config.cantilever));
    let frames = SimSem::new(scene, Some(snapshots), clock);
    let hand = HandModel {
        press_direction_haptic: teleop.haptic_from_stage() * teleop.press_direction_stage,
        spring_n_per_mm: teleop.spring_n_per_mm,
        force_scale_n_per_nn: teleop.force_scale_n_per_nn,
    };
    let haptic = SimHaptic::new(Operator::new(config.sim.operator.clone(), hand));
    Ok(Devices {
        frames: Box::new(frames),
        estimator: Box::new(VisionEstimator(tracker)),
        stage: Box::new(stage),
        haptic: Box::new(haptic),
    })
}

/// The tracker a configuration describes, calibrated on its `[tracker.calibration]`
/// reference image (for recorded or live frames from a real SEM).
pub fn tracker_from_config(config: &Config) -> anyhow::Result<Tracker> {
    let Some(clicks) = &config.tracker.calibration else {
        anyhow::bail!(
            "{}: no [tracker.calibration] section: the tracker needs a reference image and \
             clicked edge pixels (see `nanoforce calibrate --help`)",
            config.path.display()
        );
    };
    let reference = load_gray(&clicks.reference_image).with_context(|| {
        format!(
            "{}: tracker.calibration.reference_image",
            config.path.display()
        )
    })?;
    let calibration = calibrate(config, &reference, clicks)?;
    Ok(Tracker::new(
        &config.tracker,
        calibration,
        Some(config.cantilever),
    ))
}

fn calibrate(
    config: &Config,
    reference: &GrayImage,
    clicks: &CalibrationConfig,
) -> anyhow::Result<Calibration> {
    Calibration::from_reference(reference, clicks, &config.tracker).with_context(|| {
        format!(
            "calibrating the tracker on {}",
            clicks.reference_image.display()
        )
    })
}
