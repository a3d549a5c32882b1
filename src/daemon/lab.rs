//! Opening the lab a configuration describes: each device from its backend (real ones
//! through [`crate::hw::open`], `"sim"` ones from [`crate::sim::lab`]): the frame
//! source, each probe's positioner, the haptic device, and every probe's tracker
//! calibrated on its reference frame. With the simulated SEM the reference frame and
//! the clicks come from the simulator; otherwise from each `[tracker.calibration]`.
use anyhow::Context;
use image::GrayImage;

use super::haptic_loop::FeltProbe;
use super::{Devices, Estimator};
use crate::config::{CalibrationConfig, Config, ProbeConfig, SINGLE_NAME};
use crate::hw::config::FramesBackend;
use crate::hw::daq::RateOutput;
use crate::hw::frames::FrameSource;
use crate::hw::open as hw_open;
use crate::hw::Clock;
use crate::model::Cantilever;
use crate::session::frames::load_gray;
use crate::sim::config::SimProbe;
use crate::sim::frames::SimSem;
use crate::sim::lab as sim_lab;
use crate::sim::sem::SemScene;
use crate::vision::{Estimate, ProbeSet, Tracker};

// A frame carries truth for as many probes as the tracker follows in one view.
const _: () = assert!(crate::hw::frames::MAX_TRUTHS == crate::vision::MAX_PROBES);

/// The vision tracker of every probe in view as the daemon's estimator.
pub struct VisionEstimator(pub ProbeSet);

impl VisionEstimator {
    /// One probe's tracker.
    pub fn single(tracker: Tracker) -> Self {
        VisionEstimator(ProbeSet::new(vec![tracker], &[()]))
    }

    /// The live run's estimator: several probes are tracked on two threads when the
    /// host has two cores or more (a frame's latency is then the shared detection
    /// stages and the slower half of the probes), on one thread otherwise.
    pub fn live(trackers: ProbeSet) -> anyhow::Result<Self> {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        if cores < 2 {
            return Ok(VisionEstimator(trackers));
        }
        let trackers = trackers
            .on_two_threads()
            .context("starting the probes' second tracking thread")?;
        Ok(VisionEstimator(trackers))
    }
}

impl Estimator for VisionEstimator {
    fn probes(&self) -> usize {
        self.0.len()
    }

    fn estimate(&mut self, frame: &GrayImage, estimates: &mut [Estimate]) {
        self.0.track(frame, estimates)
    }
}

/// Opens every device of `config` and calibrates the trackers. A `"sim"` backend gets
/// its simulated twin; a real one is opened through [`crate::hw::open`]. Fails with a
/// message naming the device and why, before any motion can start: a backend not
/// compiled in is found before any device is touched, and a device opened before a
/// later one failed is closed again (its outputs at zero).
pub fn open(config: &Config, clock: Clock) -> anyhow::Result<Devices> {
    let felt = felt_probes(config)?;
    let devices = &config.devices;
    hw_open::check_compiled(devices)?;
    // Real frames need the configured calibrations: checked before touching a device.
    let mut configured = match devices.frames {
        FramesBackend::Sim => None,
        _ => Some(probe_trackers(config)?),
    };
    let mut stages: Vec<Box<dyn RateOutput>> = Vec::with_capacity(config.probes.len());
    let mut snapshots = Vec::with_capacity(config.probes.len());
    for (probe, positioner) in config.probes.iter().zip(&devices.positioners) {
        let opened = hw_open::daq(positioner)
            .with_context(|| format!("opening the DAQ ([{}])", positioner.section))?;
        match opened {
            Some(daq) => {
                stages.push(daq);
                snapshots.push(None);
            }
            None => {
                let (stage, snapshot) = sim_lab::stage(&config.sim, &probe.sim, &config.teleop);
                stages.push(Box::new(stage));
                snapshots.push(Some(snapshot));
            }
        }
    }
    let (frames, trackers): (Box<dyn FrameSource>, ProbeSet) =
        match hw_open::frames(&devices.frames, clock)
            .context("opening the frame source ([frames])")?
        {
            Some(frames) => match configured.take() {
                Some(trackers) => (frames, trackers),
                None => anyhow::bail!("no tracker for the configured frames"),
            },
            None => {
                let scene = sim_scene(config)?;
                let trackers = sim_trackers(config, &scene)?;
                // A probe on a real positioner hangs free in the simulated view.
                (Box::new(SimSem::new(scene, snapshots, clock)), trackers)
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
        stages
            .iter()
            .map(|s| s.name())
            .collect::<Vec<_>>()
            .join(" + "),
        haptic.name()
    );
    let names: Vec<String> = config.probes.iter().map(|p| p.name.clone()).collect();
    if config.probes.len() > 1 {
        tracing::info!(
            "probes: {}; the stylus feels {} (its second button switches)",
            names.join(", "),
            felt.iter()
                .map(|f| config.probes[f.probe].name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(Devices {
        frames,
        estimator: Box::new(VisionEstimator::live(trackers)?),
        stages,
        haptic,
        names,
        felt,
    })
}

/// The probes the stylus can feel, in the configuration's order: at least one, or the
/// run is refused with the reason.
fn felt_probes(config: &Config) -> anyhow::Result<Vec<FeltProbe>> {
    if let [probe] = config.probes.as_slice() {
        force_model(config, probe)?;
    }
    let felt: Vec<FeltProbe> = config
        .probes
        .iter()
        .enumerate()
        .filter(|(_, p)| p.felt)
        .map(|(k, p)| FeltProbe {
            probe: k,
            cantilever: p.cantilever,
            pressing_force_sign: p.pressing_force_sign,
        })
        .collect();
    if felt.is_empty() {
        anyhow::bail!(
            "{}: no [[probe]] entry is felt: `nanoforce run` renders a probe's force, which \
             needs its [probe.cantilever] (and felt = true, the default with one)",
            config.path.display()
        );
    }
    Ok(felt)
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

/// The simulated SEM of `config`'s `[sim]` sections: it bends each configured
/// cantilever (a probe without one is drawn as the built-in lab's).
fn sim_scene(config: &Config) -> anyhow::Result<SemScene> {
    if let [probe] = config.probes.as_slice() {
        force_model(config, probe)?;
    }
    let probes: Vec<(Cantilever, SimProbe)> = config
        .probes
        .iter()
        .map(|p| {
            (
                p.cantilever.unwrap_or(config.teleop.cantilever),
                p.sim.clone(),
            )
        })
        .collect();
    Ok(sim_lab::sem_scene(&config.sim, &probes, &config.teleop))
}

/// The trackers calibrated on the simulated SEM's reference frame and clicks.
fn sim_trackers(config: &Config, scene: &SemScene) -> anyhow::Result<ProbeSet> {
    let first = &config.probes[0].tracker;
    let (reference, clicks) = scene.references(first.threshold, first.window_deg);
    let trackers = config
        .probes
        .iter()
        .zip(&clicks)
        .map(|(probe, clicks)| calibrate(probe, &reference, clicks))
        .collect::<anyhow::Result<Vec<Tracker>>>()?;
    // One reference frame: the probes are seen at one scale.
    let references = vec![(); trackers.len()];
    Ok(ProbeSet::new(trackers, &references))
}

/// The trackers a live run of `config` uses: calibrated on the simulated SEM's
/// reference with `[frames] backend = "sim"`, else on each `[tracker.calibration]`.
/// Replaying a recorded session with them tracks its frames as the run did.
pub fn live_trackers(config: &Config) -> anyhow::Result<ProbeSet> {
    match config.devices.frames {
        FramesBackend::Sim => sim_trackers(config, &sim_scene(config)?),
        _ => probe_trackers(config),
    }
}

/// The trackers of every probe of `config`, in its order, each calibrated on its
/// `[tracker.calibration]` (frames from a real SEM); probes calibrated on one reference
/// image are seen at one scale.
pub fn probe_trackers(config: &Config) -> anyhow::Result<ProbeSet> {
    let trackers = config
        .probes
        .iter()
        .map(|probe| tracker_from_config(config, probe))
        .collect::<anyhow::Result<Vec<Tracker>>>()?;
    Ok(ProbeSet::new(trackers, &config.reference_images()))
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
    calibrate(probe, &reference, clicks)
}

fn calibrate(
    probe: &ProbeConfig,
    reference: &GrayImage,
    clicks: &CalibrationConfig,
) -> anyhow::Result<Tracker> {
    Tracker::from_reference(reference, clicks, &probe.tracker, probe.cantilever).with_context(
        || {
            format!(
                "calibrating the tracker{} on {}",
                match probe.name.as_str() {
                    SINGLE_NAME => String::new(),
                    name => format!(" of probe {name}"),
                },
                clicks.reference_image.display()
            )
        },
    )
}
