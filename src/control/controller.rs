//! One haptic tick of the teleoperation law: stylus position -> S100 velocity (rate
//! control with deadband, gain, speed limit and axis map), and centring springs plus the
//! scaled sensed force -> stylus force (clamped and slew-limited), under the safety rules.
//! Pure and allocation-free: the loop thread feeds it facts and applies its outputs.

use nalgebra::Vector3;

use super::gains::TeleopGains;
use super::gate::{Candidate, Gate, GateCounters, Judgement};
use super::published::Published;
use super::ramp::Ramp;
use super::safety::{Facts, PressBlock, Safety, SafetyCounters, SafetyState, Verdict};
use super::timing::{FrameTiming, TravelLog};
pub use crate::hw::haptic::HapticSample;
use crate::model::ModelTable;

/// Everything the law needs for one tick.
#[derive(Debug, Clone, Copy)]
pub struct TickInput {
    /// The daemon's monotonic clock, seconds.
    pub now_s: f64,
    /// `None`: the device is lost or its read failed.
    pub haptic: Option<HapticSample>,
    /// The newest estimate the tracker published.
    pub estimate: Option<Published>,
    /// Whether the previous stage command was written successfully.
    pub daq_ok: bool,
}

/// The commands for this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickOutput {
    pub force_n: Vector3<f64>,
    pub forces_enabled: bool,
    pub stage_velocity_um_s: Vector3<f64>,
    pub state: SafetyState,
    pub press_block: Option<PressBlock>,
    /// The sensed force being rendered (smoothed or fading), nN.
    pub rendered_force_nn: f64,
}

/// Nominal interval between estimates before any have been seen (SEM at 60 Hz).
const DEFAULT_FRAME_INTERVAL_S: f64 = 1.0 / 60.0;

/// The stage follows its velocity command within this time (the S100's lag is ~15 ms):
/// travel commanded this long before a frame's capture may still show in it.
const STAGE_SETTLE_S: f64 = 0.1;

/// The last estimate the gate accepted, as the safety rules see it.
#[derive(Debug, Clone, Copy)]
struct Accepted {
    frame_time_s: f64,
    force_nn: f64,
}

#[derive(Debug, Clone)]
pub struct Controller {
    gains: TeleopGains,
    safety: Safety,
    gate: Gate,
    timing: FrameTiming,
    travel: TravelLog,
    sensed: Ramp,
    last_seq: Option<u64>,
    accepted: Option<Accepted>,
    /// The newest estimate was a miss (not detected): nothing fresh until one is accepted.
    missed: bool,
    last_now_s: Option<f64>,
    last_speed_um_s: f64,
    /// A fade-in lasts until then: later estimates do not shorten it.
    fade_in_until_s: f64,
    last_force_n: Vector3<f64>,
}

impl Controller {
    pub fn new(gains: TeleopGains) -> Self {
        // The cantilever table is built here, not on the loop thread's first estimate.
        let _ = ModelTable::global();
        Controller {
            safety: Safety::new(gains.safety.clone()),
            gate: Gate::new(gains.safety.gate.clone(), &gains.cantilever),
            gains,
            timing: FrameTiming::default(),
            travel: TravelLog::default(),
            sensed: Ramp::new(0.0),
            last_seq: None,
            accepted: None,
            missed: true,
            last_now_s: None,
            last_speed_um_s: 0.0,
            fade_in_until_s: f64::NEG_INFINITY,
            last_force_n: Vector3::zeros(),
        }
    }

    pub fn gate_counters(&self) -> GateCounters {
        self.gate.counters()
    }

    /// The frame source's period and delay as measured from the estimates.
    pub fn frame_timing(&self) -> FrameTiming {
        self.timing
    }

    pub fn gains(&self) -> &TeleopGains {
        &self.gains
    }

    /// New gains (SIGHUP). Motion stops until the stylus is re-centred.
    pub fn set_gains(&mut self, gains: TeleopGains) {
        self.safety.set_limits(gains.safety.clone());
        self.gate.set_limits(gains.safety.gate.clone());
        self.safety.stop();
        self.gains = gains;
    }

    /// The stylus feels and drives another probe from here on (`gains`: the teleoperation
    /// with that probe's cantilever and pressing sign). Nothing known of the last probe's
    /// force carries over: the sensed force fades out, the new probe's first accepted
    /// estimate fades in, and motion stops until the stylus is back at the centre (the
    /// deadman re-engage). Allocation-free, like a tick.
    pub fn switch_probe(&mut self, gains: TeleopGains) {
        self.set_gains(gains);
        self.gate.restart(&self.gains.cantilever);
        self.accepted = None;
        self.missed = true;
        self.last_seq = None;
        self.fade();
    }

    pub fn counters(&self) -> SafetyCounters {
        self.safety.counters()
    }

    pub fn state(&self) -> SafetyState {
        self.safety.state()
    }

    pub fn tick(&mut self, input: &TickInput) -> TickOutput {
        let since_last_s = self
            .last_now_s
            .map_or(0.0, |last| (input.now_s - last).max(0.0));
        let dt_s = since_last_s.min(0.1);
        self.last_now_s = Some(input.now_s);
        // The stage moved for all of a late tick: the travel is not clamped.
        self.travel
            .push(input.now_s, self.last_speed_um_s, since_last_s);
        if let Some(estimate) = input.estimate {
            self.follow_estimate(input.now_s, &estimate);
        }
        let facts = self.facts(input);
        let verdict = self.safety.evaluate(facts);
        if !verdict.fresh {
            self.fade();
        }
        let rendered_force_nn = self.sensed.advance(dt_s);
        let Some(haptic) = input
            .haptic
            .filter(|_| verdict.state != SafetyState::HapticFault)
        else {
            self.last_force_n = Vector3::zeros();
            self.last_speed_um_s = 0.0;
            return TickOutput {
                force_n: Vector3::zeros(),
                forces_enabled: false,
                stage_velocity_um_s: Vector3::zeros(),
                state: verdict.state,
                press_block: verdict.press_block,
                rendered_force_nn,
            };
        };
        let stage_velocity_um_s = self.stage_velocity(&haptic, &verdict);
        self.last_speed_um_s = stage_velocity_um_s.norm();
        let force_n = self.stylus_force(&haptic, rendered_force_nn, dt_s);
        TickOutput {
            force_n,
            forces_enabled: true,
            stage_velocity_um_s,
            state: verdict.state,
            press_block: verdict.press_block,
            rendered_force_nn,
        }
    }

    fn facts(&self, input: &TickInput) -> Facts {
        let limits = self.safety.limits();
        let slow_frames = self.timing.too_slow(limits);
        let stale_after_s = self.timing.stale_after_s(limits);
        let fresh_estimate = self.accepted.filter(|a| {
            !self.missed && !slow_frames && input.now_s - a.frame_time_s <= stale_after_s
        });
        let centred = input
            .haptic
            .is_some_and(|h| h.position_mm.norm() <= limits.recentre_radius_mm);
        Facts {
            haptic_ok: input.haptic.is_some(),
            daq_ok: input.daq_ok,
            centred,
            fresh: fresh_estimate.is_some(),
            slow_frames,
            contact_nn: fresh_estimate.map_or(0.0, |e| e.force_nn * self.gains.pressing_force_sign),
        }
    }

    /// A new estimate: timed, then judged by the plausibility gate. An accepted one
    /// becomes the ramp's target (weighted by its sigma), reached one frame period later,
    /// or over `fade_in_ms` when re-acquired or newly confirmed; a held one changes
    /// nothing; a miss starts the fade.
    fn follow_estimate(&mut self, now_s: f64, published: &Published) {
        if self.last_seq == Some(published.seq) || published.seq == 0 {
            return;
        }
        self.last_seq = Some(published.seq);
        self.timing.observe(published.frame_time_s, now_s);
        let e = &published.estimate;
        let Some(force_nn) = e.felt_force_nn() else {
            self.missed = true;
            self.gate.miss();
            return;
        };
        let candidate = Candidate::new(
            force_nn,
            e.angle_deg.unwrap_or(f64::NAN),
            e.angle_sigma_deg.unwrap_or(f64::NAN),
            self.gate.limits(),
            &self.gains.cantilever,
            self.travel.at(published.frame_time_s - STAGE_SETTLE_S),
        );
        match self.gate.judge(candidate, self.travel.total_um()) {
            Judgement::Held => {}
            Judgement::Accept { weight, fade_in } => {
                self.missed = false;
                self.accepted = Some(Accepted {
                    frame_time_s: published.frame_time_s,
                    force_nn,
                });
                if fade_in {
                    self.fade_in_until_s = now_s + self.gate.limits().fade_in_ms * 1e-3;
                }
                // One frame period, or what is left of a fade-in.
                let period_s = self
                    .timing
                    .period_s()
                    .unwrap_or(DEFAULT_FRAME_INTERVAL_S)
                    .min(0.25);
                let duration_s = period_s.max(self.fade_in_until_s - now_s);
                self.sensed.retarget(force_nn * weight, duration_s);
            }
        }
    }

    fn fade(&mut self) {
        if self.sensed.target() != 0.0 {
            let fade_s = self.safety.limits().fade_ms * 1e-3;
            self.sensed.retarget(0.0, fade_s);
        }
    }

    fn stage_velocity(&self, haptic: &HapticSample, verdict: &Verdict) -> Vector3<f64> {
        if verdict.state != SafetyState::Engaged {
            return Vector3::zeros();
        }
        let g = &self.gains;
        let beyond = haptic.position_mm.zip_map(&g.deadband_mm, |p, band| {
            (p.abs() - band).max(0.0).copysign(p)
        });
        let mut velocity = g.stage_from_haptic * beyond.component_mul(&g.gain_um_per_s_per_mm);
        if verdict.press_block.is_some() {
            let pressing = g.press_direction_stage * verdict.press_sign;
            let along = velocity.dot(&pressing);
            if along > 0.0 {
                velocity -= pressing * along;
            }
        }
        let scale = velocity
            .iter()
            .zip(g.speed_limit_um_per_s.iter())
            .map(|(v, limit)| {
                if v.abs() > *limit {
                    limit / v.abs()
                } else {
                    1.0
                }
            })
            .fold(1.0, f64::min);
        velocity * scale
    }

    fn stylus_force(&mut self, haptic: &HapticSample, sensed_nn: f64, dt_s: f64) -> Vector3<f64> {
        let g = &self.gains;
        let spring = -haptic.position_mm.component_mul(&g.spring_n_per_mm)
            - haptic.velocity_mm_s.component_mul(&g.damping_n_s_per_mm);
        // The sample pushes the probe back against the pressing direction.
        let contact_nn = sensed_nn * g.pressing_force_sign;
        let probe_force_stage = -g.press_direction_stage * contact_nn;
        let sensed = g.haptic_from_stage() * probe_force_stage * g.force_scale_n_per_nn;
        let mut force = spring + sensed;
        let magnitude = force.norm();
        if magnitude > g.max_force_n {
            force *= g.max_force_n / magnitude;
        }
        let change = force - self.last_force_n;
        let max_step = g.force_rate_n_per_s * dt_s;
        if change.norm() > max_step {
            force = self.last_force_n + change * (max_step / change.norm());
        }
        self.last_force_n = force;
        force
    }
}
