//! One stylus, two probes on two positioners: the real daemon threads with fake devices.
//! The stylus drives and feels one probe at a time; its second button switches to the
//! next, through the deadman re-engage (motion stops until the stylus is back at the
//! centre), and the other positioner is commanded to stand still throughout.
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use image::GrayImage;
use nalgebra::Vector3;
use nanoforce::control::{HapticSample, SafetyState, TeleopGains};
use nanoforce::daemon::haptic_loop::FeltProbe;
use nanoforce::daemon::{Daemon, DaemonHandle, Devices, Estimator, LoopOptions, RunOptions};
use nanoforce::hw::daq::{DaqError, RateOutput};
use nanoforce::hw::frames::{FrameError, FrameMeta, FrameSource, NO_TRUTH};
use nanoforce::hw::haptic::{HapticDevice, HapticError, SWITCH_BUTTON};
use nanoforce::hw::Clock;
use nanoforce::vision::Estimate;

/// The force each probe measures, nN.
const FORCES_NN: [f64; 2] = [500.0, 1500.0];
/// Stylus newtons per tip nanonewton.
const SCALE_N_PER_NN: f64 = 1e-3;

#[derive(Default)]
struct Lab {
    position_mm: Mutex<Vector3<f64>>,
    buttons: AtomicU32,
    /// Each positioner's last commanded velocity.
    velocities: [Mutex<Vector3<f64>>; 2],
    force_n: Mutex<Vector3<f64>>,
    frames: AtomicU64,
}

struct Frames(Arc<Lab>, Clock);

impl FrameSource for Frames {
    fn name(&self) -> &str {
        "fake-frames"
    }
    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        std::thread::sleep(Duration::from_millis(10));
        if frame.width() != 64 {
            *frame = GrayImage::new(64, 48);
        }
        let sequence = self.0.frames.fetch_add(1, Ordering::SeqCst) + 1;
        Ok(FrameMeta {
            sequence,
            captured_s: self.1.now_s(),
            truth: NO_TRUTH,
        })
    }
}

/// Both probes detected in every frame, each at its own force.
struct TwoProbes;

impl Estimator for TwoProbes {
    fn probes(&self) -> usize {
        2
    }
    fn estimate(&mut self, _frame: &GrayImage, estimates: &mut [Estimate]) {
        for (estimate, force_nn) in estimates.iter_mut().zip(FORCES_NN) {
            *estimate = Estimate {
                detected: true,
                angle_deg: Some(1.0),
                force_nn: Some(force_nn),
                apex_px: Some([1.0, 1.0]),
                confidence: 1.0,
                angle_sigma_deg: Some(0.02),
                ..Estimate::default()
            };
        }
    }
}

struct Stage(Arc<Lab>, usize);

impl RateOutput for Stage {
    fn name(&self) -> &str {
        "fake-stage"
    }
    fn write_velocity(&mut self, _now_s: f64, v: Vector3<f64>) -> Result<(), DaqError> {
        *self.0.velocities[self.1].lock().unwrap() = v;
        Ok(())
    }
}

struct Stylus(Arc<Lab>);

impl HapticDevice for Stylus {
    fn name(&self) -> &str {
        "fake-stylus"
    }
    fn read(&mut self, _now_s: f64) -> Result<HapticSample, HapticError> {
        Ok(HapticSample {
            position_mm: *self.0.position_mm.lock().unwrap(),
            velocity_mm_s: Vector3::zeros(),
            buttons: self.0.buttons.load(Ordering::SeqCst),
        })
    }
    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError> {
        *self.0.force_n.lock().unwrap() = force_n;
        Ok(())
    }
    fn set_forces_enabled(&mut self, _enabled: bool) -> Result<(), HapticError> {
        Ok(())
    }
}

fn start(lab: &Arc<Lab>) -> DaemonHandle {
    let clock = Clock::start();
    let devices = Devices {
        frames: Box::new(Frames(lab.clone(), clock)),
        estimator: Box::new(TwoProbes),
        stages: vec![
            Box::new(Stage(lab.clone(), 0)),
            Box::new(Stage(lab.clone(), 1)),
        ],
        haptic: Box::new(Stylus(lab.clone())),
        names: vec!["left".into(), "right".into()],
        felt: vec![
            FeltProbe {
                probe: 0,
                cantilever: None,
                pressing_force_sign: None,
            },
            FeltProbe {
                probe: 1,
                cantilever: None,
                pressing_force_sign: None,
            },
        ],
    };
    let gains = TeleopGains {
        gain_um_per_s_per_mm: Vector3::repeat(0.5),
        force_rate_n_per_s: 1e6,
        force_scale_n_per_nn: SCALE_N_PER_NN,
        ..TeleopGains::default()
    };
    let options = RunOptions {
        clock,
        loop_options: LoopOptions {
            rt_priority: None,
            lock_memory: false,
            cpu_latency_us: None,
            ..LoopOptions::default()
        },
        ..RunOptions::default()
    };
    Daemon::start(gains, devices, options).unwrap()
}

/// Waits until `done` holds (or fails after 3 s, saying `what`).
fn wait_for(what: &str, done: impl Fn() -> bool) {
    for _ in 0..300 {
        if done() {
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("{what}: never happened");
}

/// At the centre the stylus force is the sensed force alone: `probe`'s, scaled.
fn feels(lab: &Lab, probe: usize) -> bool {
    let force = lab.force_n.lock().unwrap().norm();
    (force - FORCES_NN[probe] * SCALE_N_PER_NN).abs() < 0.01
}

/// The stylus pushed sideways: the felt probe's positioner moves, the other stands.
fn drives(lab: &Arc<Lab>, probe: usize) {
    *lab.position_mm.lock().unwrap() = Vector3::new(6.0, 0.0, 0.0);
    wait_for("the felt probe's positioner moves", || {
        lab.velocities[probe].lock().unwrap().x > 0.1
    });
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(
        *lab.velocities[1 - probe].lock().unwrap(),
        Vector3::zeros(),
        "the other positioner stands still"
    );
}

fn press_switch(lab: &Lab) {
    lab.buttons.store(SWITCH_BUTTON, Ordering::SeqCst);
    std::thread::sleep(Duration::from_millis(50));
    lab.buttons.store(0, Ordering::SeqCst);
}

#[test]
fn the_switch_button_moves_the_stylus_to_the_next_probe_through_the_deadman() {
    let lab = Arc::new(Lab::default());
    let handle = start(&lab);
    let shared = handle.loop_shared.clone();
    wait_for("engaged at the centre", || {
        shared.state() == SafetyState::Engaged
    });
    assert_eq!(
        shared.active_probe(),
        0,
        "the first felt probe at the start"
    );
    wait_for("the first probe's force felt", || feels(&lab, 0));
    drives(&lab, 0);

    // The switch, with the stylus away from the centre: motion stops at once and waits
    // for the re-centred stylus; holding the button switches once.
    lab.buttons.store(SWITCH_BUTTON, Ordering::SeqCst);
    wait_for("switched to the second probe", || {
        shared.active_probe() == 1
    });
    wait_for("motion stopped", || {
        shared.state() == SafetyState::WaitingForCentre
    });
    wait_for("both positioners stand still", || {
        lab.velocities
            .iter()
            .all(|v| *v.lock().unwrap() == Vector3::zeros())
    });
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(
        shared.switches.load(Ordering::Relaxed),
        1,
        "held: one switch"
    );
    lab.buttons.store(0, Ordering::SeqCst);
    assert_eq!(shared.state(), SafetyState::WaitingForCentre);

    // Back at the centre: engaged again, feeling and driving the second probe.
    *lab.position_mm.lock().unwrap() = Vector3::zeros();
    wait_for("engaged again", || shared.state() == SafetyState::Engaged);
    wait_for("the second probe's force felt", || feels(&lab, 1));
    drives(&lab, 1);

    // Once more: round to the first probe.
    press_switch(&lab);
    wait_for("back to the first probe", || shared.active_probe() == 0);
    *lab.position_mm.lock().unwrap() = Vector3::zeros();
    wait_for("engaged again", || shared.state() == SafetyState::Engaged);
    wait_for("the first probe's force felt again", || feels(&lab, 0));
    assert_eq!(shared.switches.load(Ordering::Relaxed), 2);
    handle.stop();
    let outcome = handle.wait().unwrap();
    let names: Vec<&str> = outcome
        .stats
        .probes
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(names, ["left", "right"]);
    assert!(outcome.stats.probes.iter().all(|p| p.frames.detected > 0));
}
