//! Opening the lab a configuration describes: each device from its backend (real ones
//! through [`crate::hw::open`], `"sim"` ones from [`crate::sim::lab`]), and the tracker
//! calibrated on its reference frame. With the simulated SEM the reference frame and
//! the clicks come from the simulator; otherwise from `[tracker.calibration]`.
use anyhow::Context;
use image::GrayImage;

use super::{Devices, Estimator};
use crate::config::{CalibrationConfig, Config, ProbeConfig, SINGLE_NAME};
use crate::hw::config::FramesBackend;
use crate::hw::daq::RateOutput;
use crate::hw::frames::FrameSource;
use crate::hw::open as hw_open;
use crate::hw::Clock;
use crate::model::Cantilever;
use crate::session::frames::load_gray;
use crate::sim::frames::SimSem;
use crate::sim::lab as sim_lab;
use crate::sim::sem::SemScene;
use crate::vision::{Calibration, Estimate, Tracker};

/// The vision tracker as the daemon's estimator.
pub struct VisionEstimator(pub Tracker);

impl Estimator for VisionEstimator {
    fn estimate(&mut self, frame: &GrayImage) -> Estimate {
        self.0.track(frame)
    }
}

/// Opens every device of `config` and calibrates the tracker. A `"sim"` backend gets
/// its simulated twin; a real one is opened through [`crate::hw::open`]. Fails with a
/// message naming the device and why, before any motion can start: a backend not
/// compiled in is found before any device is touched, and a device opened before a
/// later one failed is closed again (its outputs at zero).
pub fn open(config: &Config, clock: Clock) -> anyhow::Result<Devices> {
    let probe = single_probe(config)?;
    force_model(config, probe)?;
    let devices = &config.devices;
    hw_open::check_compiled(devices)?;
    // Real frames need the configured calibration: checked before touching a device.
    let mut configured_tracker = match devices.frames {
        FramesBackend::Sim => None,
        _ => Some(tracker_from_config(config, probe)?),
    };
    let (stage, snapshots): (Box<dyn RateOutput>, _) =
        match hw_open::daq(&devices.daq).context("opening the DAQ ([daq])")? {
            Some(daq) => (daq, None),
            None => {
                let (stage, snapshots) = sim_lab::stage(&config.sim);
                (Box::new(stage), Some(snapshots))
            }
        };
    let (frames, tracker): (Box<dyn FrameSource>, Tracker) =
        match hw_open::frames(&devices.frames, clock)
            .context("opening the frame source ([frames])")?
        {
            Some(frames) => match configured_tracker.take() {
                Some(tracker) => (frames, tracker),
                None => anyhow::bail!("no tracker for the configured frames"),
            },
            None => {
                let scene = sim_scene(config, probe)?;
                let tracker = sim_tracker(probe, &scene)?;
                // Without the simulated stage the simulated probe hangs free.
                (Box::new(SimSem::new(scene, snapshots, clock)), tracker)
            }
        };
    let haptic =
        match hw_open::haptic(&devices.haptic).context("opening the haptic device ([haptic])")? {
            Some(haptic) => haptic,
            None => Box::new(sim_lab::haptic(&config.sim, &config.teleop)),
        };
    if !haptic.has_force_feedback() {
        tracing::warn!("{}: position only, no force feedback", haptic.name());
    }
    tracing::info!(
        "devices: frames {}, stage {}, haptic {}",
        frames.name(),
        stage.name(),
        haptic.name()
    );
    Ok(Devices {
        frames,
        estimator: Box::new(VisionEstimator(tracker)),
        stage,
        haptic,
    })
}

/// The one probe a run tracks and feels: a configuration with several `[[probe]]`
/// entries is refused with the reason.
pub fn single_probe(config: &Config) -> anyhow::Result<&ProbeConfig> {
    match config.probes.as_slice() {
        [probe] => Ok(probe),
        probes => anyhow::bail!(
            "{}: {} [[probe]] entries: `nanoforce run` tracks and feels one probe; `nanoforce \
             replay` tracks several in one view (one results file per probe)",
            config.path.display(),
            probes.len()
        ),
    }
}

/// The cantilever that turns the tip's bending into a force: a run renders that force,
/// so a probe without `[cantilever]` is refused with the reason.
fn force_model(config: &Config, probe: &ProbeConfig) -> anyhow::Result<Cantilever> {
    probe.cantilever.ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no [cantilever] section: `nanoforce run` renders the probe's force, which \
             needs the cantilever (length_um and a stiffness, config/probe.example.toml). A \
             probe without one (a needle, a gripper jaw) can be calibrated and replayed: its \
             pose, without a force",
            config.path.display()
        )
    })
}

/// The simulated SEM of `config`'s `[sim]` sections (it bends the configured cantilever).
fn sim_scene(config: &Config, probe: &ProbeConfig) -> anyhow::Result<SemScene> {
    Ok(sim_lab::sem_scene(
        &config.sim,
        force_model(config, probe)?,
        &config.teleop,
    ))
}

/// The tracker calibrated on the simulated SEM's reference frame and clicks.
fn sim_tracker(probe: &ProbeConfig, scene: &SemScene) -> anyhow::Result<Tracker> {
    let (reference, clicks) = scene.reference(probe.tracker.threshold, probe.tracker.window_deg);
    let calibration = calibrate(probe, &reference, &clicks)?;
    Ok(Tracker::new(&probe.tracker, calibration, probe.cantilever))
}

/// The tracker a live run of `config` uses: calibrated on the simulated SEM's reference
/// with `[frames] backend = "sim"`, else on `[tracker.calibration]`. Replaying a
/// recorded session with it tracks its frames as the run did.
pub fn live_tracker(config: &Config) -> anyhow::Result<Tracker> {
    let probe = single_probe(config)?;
    match config.devices.frames {
        FramesBackend::Sim => sim_tracker(probe, &sim_scene(config, probe)?),
        _ => tracker_from_config(config, probe),
    }
}

/// The trackers of every probe of `config`, in its order, each calibrated on its
/// `[tracker.calibration]` (replaying frames from a real SEM).
pub fn probe_trackers(config: &Config) -> anyhow::Result<Vec<Tracker>> {
    config
        .probes
        .iter()
        .map(|probe| tracker_from_config(config, probe))
        .collect()
}

/// The tracker of one probe of `config`, calibrated on its `[tracker.calibration]`
/// reference image (for recorded or live frames from a real SEM).
pub fn tracker_from_config(config: &Config, probe: &ProbeConfig) -> anyhow::Result<Tracker> {
    let section = probe.key("tracker.calibration");
    let Some(clicks) = &probe.tracker.calibration else {
        anyhow::bail!(
            "{}: no [{section}] section: the tracker needs a reference image and clicked \
             edge pixels (see `nanoforce calibrate --help`)",
            config.path.display()
        );
    };
    let reference = load_gray(&clicks.reference_image)
        .with_context(|| format!("{}: {section}.reference_image", config.path.display()))?;
    let calibration = calibrate(probe, &reference, clicks)?;
    Ok(Tracker::new(&probe.tracker, calibration, probe.cantilever))
}

fn calibrate(
    probe: &ProbeConfig,
    reference: &GrayImage,
    clicks: &CalibrationConfig,
) -> anyhow::Result<Calibration> {
    Calibration::from_reference(reference, clicks, &probe.tracker).with_context(|| {
        format!(
            "calibrating the tracker{} on {}",
            match probe.name.as_str() {
                SINGLE_NAME => String::new(),
                name => format!(" of probe {name}"),
            },
            clicks.reference_image.display()
        )
    })
}
