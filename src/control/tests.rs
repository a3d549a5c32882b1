//! The teleoperation law and each safety rule, tick by tick. The law's own tests pass
//! every estimate through the plausibility gate (a bound of 1e9 sigmas, a 16 ms
//! fade-in); the gate's holding, confirming and fading are tested at the end.
use nalgebra::Vector3;

use super::*;
use crate::vision::Estimate;

const DT: f64 = 0.001;

fn gains() -> TeleopGains {
    TeleopGains {
        deadband_mm: Vector3::repeat(2.0),
        gain_um_per_s_per_mm: Vector3::repeat(1.0),
        speed_limit_um_per_s: Vector3::repeat(10.0),
        spring_n_per_mm: Vector3::repeat(0.1),
        damping_n_s_per_mm: Vector3::zeros(),
        force_scale_n_per_nn: 1e-3,
        press_direction_stage: Vector3::new(0.0, 0.0, -1.0),
        pressing_force_sign: 1.0,
        max_force_n: 3.0,
        force_rate_n_per_s: 1e6,
        ..TeleopGains::default()
    }
    .with_gate(GateLimits {
        sigmas: 1e9,
        confirm_frames: 1,
        fade_in_ms: 16.0,
        ..GateLimits::default()
    })
}

/// The shipped gate.
fn gated() -> TeleopGains {
    TeleopGains {
        safety: SafetyLimits::default(),
        ..gains()
    }
}

trait WithGate {
    fn with_gate(self, gate: GateLimits) -> Self;
}

impl WithGate for TeleopGains {
    fn with_gate(mut self, gate: GateLimits) -> Self {
        self.safety.gate = gate;
        self
    }
}

/// Drives a controller with a stylus position and a 60 Hz estimate stream.
struct Bench {
    c: Controller,
    now_s: f64,
    seq: u64,
    estimate: Option<Published>,
    position_mm: Vector3<f64>,
    haptic_ok: bool,
    daq_ok: bool,
}

impl Bench {
    fn new() -> Self {
        Bench::with(gains())
    }

    fn with(gains: TeleopGains) -> Self {
        Bench {
            c: Controller::new(gains),
            now_s: 0.0,
            seq: 0,
            estimate: None,
            position_mm: Vector3::zeros(),
            haptic_ok: true,
            daq_ok: true,
        }
    }

    /// Publishes an estimate of a frame captured `age_s` ago.
    fn publish(&mut self, force_nn: f64, detected: bool, age_s: f64) {
        self.seq += 1;
        self.estimate = Some(Published {
            seq: self.seq,
            frame_time_s: self.now_s - age_s,
            estimate: Estimate {
                detected,
                force_nn: Some(force_nn),
                angle_sigma_deg: Some(0.02),
                ..Estimate::default()
            },
            ..Published::default()
        });
    }

    fn tick(&mut self) -> TickOutput {
        self.now_s += DT;
        let haptic = self.haptic_ok.then_some(HapticSample {
            position_mm: self.position_mm,
            velocity_mm_s: Vector3::zeros(),
            buttons: 0,
        });
        self.c.tick(&TickInput {
            now_s: self.now_s,
            haptic,
            estimate: self.estimate,
            daq_ok: self.daq_ok,
        })
    }

    fn run(&mut self, ticks: usize) -> TickOutput {
        let mut out = self.tick();
        for _ in 1..ticks {
            out = self.tick();
        }
        out
    }

    /// Centre the stylus with a fresh zero-force estimate so motion is engaged.
    fn engage(&mut self) {
        self.position_mm = Vector3::zeros();
        self.publish(0.0, true, 0.0);
        let out = self.run(2);
        assert_eq!(out.state, SafetyState::Engaged);
        assert_eq!(out.press_block, None);
    }
}

#[test]
fn no_motion_until_the_stylus_has_been_centred() {
    let mut b = Bench::new();
    b.publish(0.0, true, 0.0);
    b.position_mm = Vector3::new(5.0, 0.0, 0.0);
    let out = b.run(10);
    assert_eq!(out.state, SafetyState::WaitingForCentre);
    assert_eq!(out.stage_velocity_um_s, Vector3::zeros());
    b.engage();
    b.position_mm = Vector3::new(5.0, 0.0, 0.0);
    let out = b.tick();
    assert!((out.stage_velocity_um_s.x - 3.0).abs() < 1e-12, "{out:?}");
}

#[test]
fn rate_control_with_deadband_gain_limit_and_axis_map() {
    let mut b = Bench::new();
    b.c.set_gains(TeleopGains {
        stage_from_haptic: nalgebra::Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        ..gains()
    });
    b.engage();
    b.position_mm = Vector3::new(1.9, 0.0, 0.0);
    assert_eq!(
        b.tick().stage_velocity_um_s,
        Vector3::zeros(),
        "inside the deadband"
    );
    b.position_mm = Vector3::new(4.0, 0.0, 0.0);
    let v = b.tick().stage_velocity_um_s;
    assert!(
        (v - Vector3::new(0.0, -2.0, 0.0)).norm() < 1e-12,
        "haptic x -> stage -y: {v}"
    );
    b.position_mm = Vector3::new(52.0, 22.0, 0.0);
    let v = b.tick().stage_velocity_um_s;
    // (50, 20) um/s before the limit: scaled by 10/50, direction kept.
    assert!((v - Vector3::new(4.0, -10.0, 0.0)).norm() < 1e-12, "{v}");
}

#[test]
fn springs_centre_the_stylus() {
    let mut b = Bench::new();
    b.engage();
    b.position_mm = Vector3::new(3.0, -2.0, 1.0);
    let out = b.tick();
    assert!((out.force_n - Vector3::new(-0.3, 0.2, -0.1)).norm() < 1e-12);
    assert!(out.forces_enabled);
}

#[test]
fn sensed_force_is_rendered_against_pressing_without_steps() {
    let mut b = Bench::new();
    b.engage();
    // The next frame of a 60 Hz stream.
    b.run(15);
    b.publish(1000.0, true, 0.0);
    let mut previous = b.tick().force_n.z;
    let mut largest_step: f64 = 0.0;
    for _ in 0..40 {
        let z = b.tick().force_n.z;
        largest_step = largest_step.max((z - previous).abs());
        previous = z;
    }
    // 1000 nN * 1e-3 N/nN = 1 N, pushing the stylus back (+z; pressing is -z).
    assert!((previous - 1.0).abs() < 1e-9, "{previous}");
    assert!(
        largest_step < 0.1,
        "the 60 Hz estimate must be ramped, step {largest_step}"
    );
}

#[test]
fn stale_estimate_fades_force_and_stops_approach_until_recentred() {
    let mut b = Bench::new();
    b.engage();
    b.publish(2000.0, true, 0.0);
    let out = b.run(40);
    assert!((out.rendered_force_nn - 2000.0).abs() < 1e-6);
    // No estimate for longer than stale_after_ms (100 ms): the force fades over 200 ms.
    let out = b.run(61);
    assert_eq!(out.press_block, Some(PressBlock::Stale));
    assert_eq!(b.c.counters().stale_events, 1);
    let half = b.run(100).rendered_force_nn;
    assert!(
        (half - 1000.0).abs() < 30.0,
        "halfway through the fade: {half}"
    );
    assert_eq!(b.run(110).rendered_force_nn, 0.0);
    // Pressing (stage -z, i.e. haptic -z) is refused, retreat and lateral motion allowed.
    b.position_mm = Vector3::new(4.0, 0.0, -6.0);
    let v = b.tick().stage_velocity_um_s;
    assert_eq!(v.z, 0.0);
    assert!(v.x > 0.0);
    b.position_mm = Vector3::new(0.0, 0.0, 6.0);
    assert!(b.tick().stage_velocity_um_s.z > 0.0, "retreat allowed");
    // A fresh estimate alone does not resume the approach ...
    b.publish(0.0, true, 0.0);
    b.position_mm = Vector3::new(0.0, 0.0, -6.0);
    assert_eq!(b.tick().stage_velocity_um_s.z, 0.0);
    // ... re-centring does.
    b.position_mm = Vector3::zeros();
    b.tick();
    b.position_mm = Vector3::new(0.0, 0.0, -6.0);
    assert!(b.tick().stage_velocity_um_s.z < 0.0);
}

#[test]
fn undetected_tip_counts_as_stale_and_gives_no_force() {
    let mut b = Bench::new();
    b.engage();
    b.publish(1500.0, true, 0.0);
    b.run(30);
    b.publish(f64::NAN, false, 0.0);
    let out = b.tick();
    assert_eq!(out.press_block, Some(PressBlock::Stale));
    assert!(out.rendered_force_nn.is_finite());
    assert_eq!(b.run(250).rendered_force_nn, 0.0);
}

#[test]
fn force_above_the_limit_refuses_pressing_but_allows_retreat() {
    let mut b = Bench::new();
    b.engage();
    b.publish(12_000.0, true, 0.0);
    b.position_mm = Vector3::new(0.0, 0.0, -6.0);
    let out = b.tick();
    assert_eq!(out.press_block, Some(PressBlock::ForceLimit));
    assert_eq!(out.stage_velocity_um_s.z, 0.0);
    assert_eq!(b.c.counters().force_limit_events, 1);
    b.position_mm = Vector3::new(0.0, 0.0, 6.0);
    assert!(b.tick().stage_velocity_um_s.z > 0.0);
    // Pulling too hard (adhesion) refuses pulling harder instead.
    b.publish(-12_000.0, true, 0.0);
    assert_eq!(b.tick().stage_velocity_um_s.z, 0.0);
    b.position_mm = Vector3::new(0.0, 0.0, -6.0);
    assert!(b.tick().stage_velocity_um_s.z < 0.0);
}

#[test]
fn lost_haptic_device_zeroes_velocity_and_forces_in_the_same_tick() {
    let mut b = Bench::new();
    b.engage();
    b.position_mm = Vector3::new(10.0, 0.0, 0.0);
    assert!(b.tick().stage_velocity_um_s.x > 0.0);
    b.haptic_ok = false;
    let out = b.tick();
    assert_eq!(out.stage_velocity_um_s, Vector3::zeros());
    assert_eq!(out.force_n, Vector3::zeros());
    assert!(!out.forces_enabled);
    assert_eq!(out.state, SafetyState::HapticFault);
    assert_eq!(b.c.counters().faults, 1);
    // Back, but still off-centre: no motion until re-centred.
    b.haptic_ok = true;
    let out = b.run(5);
    assert_eq!(out.state, SafetyState::WaitingForCentre);
    assert_eq!(out.stage_velocity_um_s, Vector3::zeros());
    b.position_mm = Vector3::zeros();
    assert_eq!(b.tick().state, SafetyState::Engaged);
}

#[test]
fn daq_error_is_a_fault_until_writes_succeed_and_the_stylus_is_centred() {
    let mut b = Bench::new();
    b.engage();
    b.position_mm = Vector3::new(10.0, 0.0, 0.0);
    b.daq_ok = false;
    let out = b.tick();
    assert_eq!(out.state, SafetyState::DaqFault);
    assert_eq!(out.stage_velocity_um_s, Vector3::zeros());
    assert_eq!(b.c.counters().faults, 1);
    b.run(10);
    assert_eq!(b.c.counters().faults, 1, "one fault, not one per tick");
    b.daq_ok = true;
    assert_eq!(b.tick().state, SafetyState::WaitingForCentre);
    b.position_mm = Vector3::zeros();
    assert_eq!(b.tick().state, SafetyState::Engaged);
}

#[test]
fn total_force_is_clamped_and_slew_limited() {
    let mut b = Bench::new();
    b.c.set_gains(TeleopGains {
        force_rate_n_per_s: 100.0,
        ..gains()
    });
    b.engage();
    b.position_mm = Vector3::new(-100.0, 0.0, 0.0); // spring would be 10 N
    let first = b.tick().force_n;
    assert!((first.x - 0.1).abs() < 1e-9, "100 N/s over 1 ms: {first}");
    let settled = b.run(100).force_n;
    assert!(
        (settled.norm() - 3.0).abs() < 1e-9,
        "clamped to max_force_n: {settled}"
    );
}

#[test]
fn new_gains_stop_motion_until_recentred() {
    let mut b = Bench::new();
    b.engage();
    b.position_mm = Vector3::new(10.0, 0.0, 0.0);
    assert!(b.tick().stage_velocity_um_s.x > 0.0);
    b.c.set_gains(gains());
    assert_eq!(b.tick().stage_velocity_um_s, Vector3::zeros());
}

/// Publishes `force_nn` as a 60 Hz stream for `frames` frames, ticking in between.
fn stream(b: &mut Bench, force_nn: f64, sigma_deg: f64, frames: usize) -> TickOutput {
    let mut out = b.tick();
    for _ in 0..frames {
        b.publish(force_nn, true, 0.0);
        if let Some(e) = b.estimate.as_mut() {
            e.estimate.angle_sigma_deg = Some(sigma_deg);
        }
        out = b.run(17);
    }
    out
}

/// The force of a `angle_deg` rotation of the default cantilever.
fn force_at(angle_deg: f64) -> f64 {
    TeleopGains::default().cantilever.force_nn(angle_deg).value
}

#[test]
fn the_gate_holds_a_jump_without_stage_travel_and_fades_in_once_confirmed() {
    let mut b = Bench::with(gated());
    b.position_mm = Vector3::zeros();
    // The first force is confirmed by four agreeing frames, then fades in over 150 ms.
    let out = stream(&mut b, 0.0, 0.02, 4);
    assert_eq!(out.press_block, None, "{out:?}");
    let out = stream(&mut b, 0.0, 0.02, 10);
    assert_eq!(out.rendered_force_nn, 0.0);
    // A false detection of a 15 deg bend, frame after frame at random-looking angles:
    // held, never rendered, counted.
    let mut largest: f64 = 0.0;
    for angle in [15.0, -12.0, 18.5, 11.0, -19.0, 13.3, 16.1, -10.4] {
        let out = stream(&mut b, force_at(angle), 0.03, 1);
        largest = largest.max(out.rendered_force_nn.abs());
    }
    assert_eq!(largest, 0.0);
    // Three held while the first force was confirmed, eight false bends.
    assert_eq!(b.c.gate_counters().held, 3 + 8);
    // A false bend that persists frame after frame, with no stage motion, is never felt.
    let jump = force_at(1.0);
    let out = stream(&mut b, jump, 0.02, 20);
    assert_eq!(out.rendered_force_nn, 0.0);
    assert_eq!(b.c.gate_counters().held, 3 + 8 + 20);
    assert_eq!(
        out.press_block,
        Some(PressBlock::Stale),
        "not fresh: pressing refused"
    );
}

#[test]
fn a_release_is_confirmed_and_fades_in_without_a_step() {
    let mut b = Bench::with(gated());
    // The first force after start is confirmed by four agreeing frames.
    let jump = force_at(1.0);
    let out = stream(&mut b, jump, 0.02, 14);
    assert!((out.rendered_force_nn - jump).abs() < 1e-3, "{out:?}");
    // The tip springs back to zero (released) with no stage motion: four frames
    // confirm it, and the force goes over gate_fade_in_ms, not in one frame.
    let mut previous = out.rendered_force_nn;
    let mut largest_step: f64 = 0.0;
    for _ in 0..20 {
        b.publish(0.0, true, 0.0);
        for _ in 0..17 {
            let v = b.tick().rendered_force_nn;
            largest_step = largest_step.max((v - previous).abs());
            previous = v;
        }
    }
    assert!(previous.abs() < 1e-6, "{previous}");
    assert!(
        largest_step <= jump / 150.0 + 1e-9,
        "faded: step {largest_step}"
    );
    assert_eq!(b.c.gate_counters().confirmed, 2);
}

#[test]
fn the_gate_follows_real_contact_driven_by_the_stage() {
    let mut b = Bench::with(gated());
    stream(&mut b, 0.0, 0.02, 14);
    let held_before = b.c.gate_counters().held;
    // Pressing at 10 um/s (the stylus 12 mm down: 10 mm beyond the deadband, limited);
    // the default probe's k is 60 nN/um, a rigid sample gives 600 nN/s.
    b.position_mm = Vector3::new(0.0, 0.0, -12.0);
    let mut force_nn = 0.0;
    for _ in 0..60 {
        force_nn += 600.0 / 60.0;
        let out = stream(&mut b, force_nn, 0.02, 1);
        assert!(out.stage_velocity_um_s.z < 0.0, "{out:?}");
    }
    assert_eq!(b.c.gate_counters().held, held_before);
    let rendered = b.run(20).rendered_force_nn;
    assert!(
        (rendered - force_nn).abs() < 1e-6,
        "{rendered} vs {force_nn}"
    );
}

#[test]
fn a_reacquired_force_fades_in_and_a_vague_one_is_attenuated() {
    let mut b = Bench::with(gated());
    stream(&mut b, 300.0, 0.02, 14);
    assert!((b.tick().rendered_force_nn - 300.0).abs() < 1e-6);
    // Lost for three frames: the force fades; found again at the same force, it fades
    // back in over 150 ms instead of one frame.
    b.publish(f64::NAN, false, 0.0);
    b.run(50);
    let low = b.tick().rendered_force_nn;
    assert!(low < 300.0 * 0.8, "{low}");
    let out = stream(&mut b, 300.0, 0.02, 1);
    assert!(out.rendered_force_nn < 300.0 - 1.0, "fading in: {out:?}");
    let out = stream(&mut b, 300.0, 0.02, 10);
    assert!((out.rendered_force_nn - 300.0).abs() < 1e-3, "{out:?}");
    // sigma 0.2 deg, twice full_sigma_deg: rendered at a quarter, counted.
    let out = stream(&mut b, 300.0, 0.2, 3);
    assert!((out.rendered_force_nn - 75.0).abs() < 1e-3, "{out:?}");
    assert_eq!(b.c.gate_counters().attenuated, 3);
}

#[test]
fn slow_frames_refuse_force_feedback_without_stale_events() {
    let mut b = Bench::with(gated());
    stream(&mut b, 0.0, 0.02, 14);
    // One frame every 600 ms: after the period is measured, no force, no pressing.
    for _ in 0..6 {
        b.publish(0.0, true, 0.0);
        b.run(600);
    }
    let out = b.tick();
    assert_eq!(out.press_block, Some(PressBlock::SlowFrames));
    // Only the first two gaps, before two long intervals in a row measure the scan.
    assert!(b.c.counters().stale_events <= 2, "{:?}", b.c.counters());
}
