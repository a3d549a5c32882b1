//! One haptic tick of the teleoperation law: stylus position -> S100 velocity (rate
//! control with deadband, gain, speed limit and axis map), and centring springs plus the
//! scaled sensed force -> stylus force (clamped and slew-limited), under the safety rules.
//! Pure and allocation-free: the loop thread feeds it facts and applies its outputs.

use nalgebra::Vector3;

use super::gains::TeleopGains;
use super::ramp::Ramp;
use super::safety::{Facts, PressBlock, Safety, SafetyCounters, SafetyState, Verdict};

/// The stylus as read this tick (haptic frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HapticSample {
    pub position_mm: Vector3<f64>,
    pub velocity_mm_s: Vector3<f64>,
}

/// The newest force estimate published by the tracker.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensedForce {
    /// Increments with every published estimate.
    pub seq: u64,
    /// When the frame was captured, seconds on the daemon's monotonic clock.
    pub frame_time_s: f64,
    pub detected: bool,
    /// Signed as the tip angle; meaningful only when `detected`.
    pub force_nn: f64,
}

/// Everything the law needs for one tick.
#[derive(Debug, Clone, Copy)]
pub struct TickInput {
    /// The daemon's monotonic clock, seconds.
    pub now_s: f64,
    /// `None`: the device is lost or its read failed.
    pub haptic: Option<HapticSample>,
    pub estimate: Option<SensedForce>,
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

#[derive(Debug, Clone)]
pub struct Controller {
    gains: TeleopGains,
    safety: Safety,
    sensed: Ramp,
    last_seq: Option<u64>,
    last_estimate_s: Option<f64>,
    frame_interval_s: f64,
    last_now_s: Option<f64>,
    last_force_n: Vector3<f64>,
}

impl Controller {
    pub fn new(gains: TeleopGains) -> Self {
        Controller {
            safety: Safety::new(gains.safety.clone()),
            gains,
            sensed: Ramp::new(0.0),
            last_seq: None,
            last_estimate_s: None,
            frame_interval_s: DEFAULT_FRAME_INTERVAL_S,
            last_now_s: None,
            last_force_n: Vector3::zeros(),
        }
    }

    pub fn gains(&self) -> &TeleopGains {
        &self.gains
    }

    /// New gains (SIGHUP). Motion stops until the stylus is re-centred.
    pub fn set_gains(&mut self, gains: TeleopGains) {
        self.safety.set_limits(gains.safety.clone());
        self.safety.stop();
        self.gains = gains;
    }

    pub fn counters(&self) -> SafetyCounters {
        self.safety.counters()
    }

    pub fn state(&self) -> SafetyState {
        self.safety.state()
    }

    pub fn tick(&mut self, input: &TickInput) -> TickOutput {
        let dt_s = match self.last_now_s {
            Some(last) => (input.now_s - last).clamp(0.0, 0.1),
            None => 0.0,
        };
        self.last_now_s = Some(input.now_s);
        let facts = self.facts(input);
        let verdict = self.safety.evaluate(facts);
        self.follow_estimate(input, verdict.fresh);
        let rendered_force_nn = self.sensed.advance(dt_s);
        let Some(haptic) = input
            .haptic
            .filter(|_| verdict.state != SafetyState::HapticFault)
        else {
            self.last_force_n = Vector3::zeros();
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
        let fresh_estimate = input.estimate.filter(|e| {
            e.detected
                && e.force_nn.is_finite()
                && (input.now_s - e.frame_time_s) * 1e3 <= limits.stale_after_ms
        });
        let centred = input
            .haptic
            .is_some_and(|h| h.position_mm.norm() <= limits.recentre_radius_mm);
        Facts {
            haptic_ok: input.haptic.is_some(),
            daq_ok: input.daq_ok,
            centred,
            fresh: fresh_estimate.is_some(),
            contact_nn: fresh_estimate.map_or(0.0, |e| e.force_nn * self.gains.pressing_force_sign),
        }
    }

    /// A new fresh estimate becomes the ramp's target, reached one frame interval later;
    /// losing it starts the fade to zero (once, so the fade keeps its rate).
    fn follow_estimate(&mut self, input: &TickInput, fresh: bool) {
        let Some(estimate) = input.estimate else {
            self.fade();
            return;
        };
        if !fresh {
            self.fade();
            return;
        }
        if self.last_seq == Some(estimate.seq) {
            return;
        }
        self.last_seq = Some(estimate.seq);
        if let Some(prev) = self.last_estimate_s {
            let interval = (input.now_s - prev).clamp(0.001, 0.25);
            self.frame_interval_s += 0.2 * (interval - self.frame_interval_s);
        }
        self.last_estimate_s = Some(input.now_s);
        self.sensed
            .retarget(estimate.force_nn, self.frame_interval_s);
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
