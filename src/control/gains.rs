//! `[teleop]` and `[safety]`: the teleoperation gains and safety limits, mirrored from
//! TOML and validated. These are the only settings SIGHUP may change while running.
//!
//! Frames: `haptic` is the PHANToM's frame (millimetres, newtons), `stage` the S100's
//! (micrometres per second). `stage_from_haptic` maps a haptic direction to a stage
//! direction and must be orthonormal (a rotation or signed permutation), so forces
//! travel back with its transpose.

use nalgebra::{Matrix3, Vector3};
use serde::Deserialize;

use crate::checks::{Checker, ConfigError, List, Range};
use crate::model::Cantilever;

// The accepted ranges, documented with the same words in config/sim.toml.
/// A haptic servo loop runs at 500 Hz to 1 kHz; below 100 Hz a stiff spring chatters,
/// above 4 kHz no device driver keeps up.
const RATE_HZ: Range = Range::new(100.0, 4000.0, "Hz");
/// Stylus travel (deadband, re-centre radius): a PHANToM's smallest workspace axis is
/// about 70 mm (Touch/Omni), so more than 20 mm from the centre leaves no room to move;
/// below 0.1 mm is hand tremor.
const TRAVEL_MM: Range = Range::new(0.1, 20.0, "mm");
/// 0 locks the axis; 1000 um/s per mm sends the stage 1 mm/s for 1 mm of stylus.
const GAIN_UM_PER_S_PER_MM: Range = Range::new(0.0, 1000.0, "um/s per mm");
/// 0 locks the axis; 5 mm/s is beyond what a nanomanipulator stage moves under an SEM
/// (the whole 12 mm travel of an S100 in under 3 s).
const SPEED_UM_PER_S: Range = Range::new(0.0, 5000.0, "um/s");
/// A PHANToM renders stiffness up to about 1 to 3.5 N/mm (Touch to Premium).
const SPRING_N_PER_MM: Range = Range::new(0.0, 5.0, "N/mm");
/// Stable virtual damping on a 1 kHz PHANToM loop is of the order of 0.001 N s/mm.
const DAMPING_N_S_PER_MM: Range = Range::new(0.0, 0.02, "N s/mm");
/// Stylus newtons per tip nanonewton: 1 makes 1 nN (the softest probe's resolution) a
/// full-scale push; 1e-8 makes 10 mN (the stiffest probe's range) 0.1 N. 0 would hide
/// the force the operator is there to feel.
const FORCE_SCALE_N_PER_NN: Range = Range::new(1e-8, 1.0, "N/nN");
/// A PHANToM's force: the Touch peaks at 3.3 N, the Premium 1.5 at 8.5 N.
const STYLUS_FORCE_N: Range = Range::new(0.01, 10.0, "N");
/// 1000 N/s ramps 10 N in 10 ms, faster than a hand notices; 1 N/s takes 3 s for 3 N.
const FORCE_RATE_N_PER_S: Range = Range::new(1.0, 1000.0, "N/s");
/// A frame is 17 to 40 ms apart and some 20 ms late; past 2 s the force felt is from
/// a scene that has moved on.
const STALE_AFTER_MS: Range = Range::new(10.0, 2000.0, "ms");
/// From a step (1 ms, one tick) to a slow 2 s fade.
const FADE_MS: Range = Range::new(1.0, 2000.0, "ms");
/// 1 nN to 10 mN: what a cantilever of the accepted stiffness (up to 1000 N/m) feels
/// at up to 10 um of deflection.
const CONTACT_FORCE_NN: Range = Range::new(1.0, 1e7, "nN");
/// The plausibility gate's allowance in the estimate's standard errors: below 1 noise
/// alone holds estimates, above 20 any jump passes.
const GATE_SIGMAS: Range = Range::new(1.0, 20.0, "sigma");
/// The floor of an estimate's angle sigma: the tracker's best is about 0.005 deg.
const GATE_MIN_SIGMA_DEG: Range = Range::new(0.001, 1.0, "deg");
/// Up to this sigma a force is felt in full; the tracker's sigma rarely passes 0.3 deg.
const GATE_FULL_SIGMA_DEG: Range = Range::new(0.01, 5.0, "deg");
/// Frames that must agree to confirm a release: at 10 to 60 frames/s, 100 is 2 to 10 s.
const GATE_CONFIRM_FRAMES: Range = Range::new(1.0, 100.0, "frames");
/// Staleness in measured frame periods (plus the measured delay): below 1 every frame
/// goes stale before the next arrives.
const STALE_PERIOD_MARGIN: Range = Range::new(1.0, 10.0, "periods");
/// Frames further apart than this are a slow scan (no force feedback): 50 ms is 20
/// frames/s, 10 s a slow high-resolution scan.
const MAX_FRAME_PERIOD_MS: Range = Range::new(50.0, 10000.0, "ms");

/// Raw `[teleop]` section; every field optional, defaults in [`TeleopGains::default`].
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTeleop {
    rate_hz: Option<f64>,
    deadband_mm: Option<List<f64, 3>>,
    gain_um_per_s_per_mm: Option<List<f64, 3>>,
    speed_limit_um_per_s: Option<List<f64, 3>>,
    stage_from_haptic: Option<List<List<f64, 3>, 3>>,
    spring_n_per_mm: Option<List<f64, 3>>,
    damping_n_s_per_mm: Option<List<f64, 3>>,
    force_scale_n_per_nn: Option<f64>,
    press_direction_stage: Option<List<f64, 3>>,
    pressing_force_sign: Option<f64>,
    max_force_n: Option<f64>,
    force_rate_n_per_s: Option<f64>,
}

/// Raw `[safety]` section.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSafety {
    stale_after_ms: Option<f64>,
    fade_ms: Option<f64>,
    max_contact_force_nn: Option<f64>,
    recentre_radius_mm: Option<f64>,
    // The plausibility gate and the frame timing (defaults in `SafetyLimits::default`).
    gate_sigmas: Option<f64>,
    gate_min_sigma_deg: Option<f64>,
    gate_full_sigma_deg: Option<f64>,
    gate_confirm_frames: Option<i64>,
    gate_fade_in_ms: Option<f64>,
    stale_period_margin: Option<f64>,
    max_frame_period_ms: Option<f64>,
}

/// Validated teleoperation law parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct TeleopGains {
    /// Haptic loop rate.
    pub rate_hz: f64,
    /// Per haptic axis: stylus travel from centre that commands no motion.
    pub deadband_mm: Vector3<f64>,
    /// Per haptic axis: stage speed per millimetre beyond the deadband.
    pub gain_um_per_s_per_mm: Vector3<f64>,
    /// Per stage axis: the commanded speed is scaled down (direction kept) to fit.
    pub speed_limit_um_per_s: Vector3<f64>,
    pub stage_from_haptic: Matrix3<f64>,
    /// Centring virtual springs and damping, per haptic axis.
    pub spring_n_per_mm: Vector3<f64>,
    pub damping_n_s_per_mm: Vector3<f64>,
    /// Newtons on the stylus per nanonewton sensed at the tip.
    pub force_scale_n_per_nn: f64,
    /// Unit vector, stage frame: moving the stage this way presses the tip on the sample.
    pub press_direction_stage: Vector3<f64>,
    /// +1 or -1: the sign of the tracked force while the tip presses on the sample.
    pub pressing_force_sign: f64,
    /// The device's force limit: the total force is clamped to this magnitude.
    pub max_force_n: f64,
    /// Slew limit of the total force.
    pub force_rate_n_per_s: f64,
    pub safety: SafetyLimits,
    /// The probe's cantilever (from `[cantilever]`, not reloaded): its spring constant
    /// bounds how fast the sensed force can change, its table turns angle sigmas into
    /// force sigmas. Default: the built-in simulated lab's probe.
    pub cantilever: Cantilever,
}

/// Validated `[safety]` section.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyLimits {
    /// An estimate older than this (from its frame's time) is stale.
    pub stale_after_ms: f64,
    /// Stale or lost: the sensed force fades to zero over this time.
    pub fade_ms: f64,
    /// Above this sensed force, motion that would press harder is refused.
    pub max_contact_force_nn: f64,
    /// The stylus is "back at the centre" (deadman re-engage) within this radius.
    pub recentre_radius_mm: f64,
    /// The plausibility gate between the estimate and the rendered force.
    pub gate: GateLimits,
    /// An estimate is stale when older than max(`stale_after_ms`, this many measured
    /// frame periods + the measured capture-to-arrival delay).
    pub stale_period_margin: f64,
    /// Frames further apart than this (a slow scan) refuse force feedback: positioning
    /// only, pressing refused.
    pub max_frame_period_ms: f64,
}

/// How the plausibility gate judges an estimate (see `super::gate`).
#[derive(Debug, Clone, PartialEq)]
pub struct GateLimits {
    /// Allowed change: k x commanded stage travel + this many force sigmas.
    pub sigmas: f64,
    /// Floor of the angle sigma an estimate is judged with (and the sigma of an
    /// estimate that has none), degrees.
    pub min_sigma_deg: f64,
    /// Up to this angle sigma a force is rendered in full; above it the force is scaled
    /// by (this / sigma)^2, and the sigma allowance of the jump bound stops growing.
    pub full_sigma_deg: f64,
    /// A larger jump toward zero (a release), or the first force after start, is
    /// rendered once this many consecutive frames agree with it.
    pub confirm_frames: u32,
    /// A re-acquired or newly confirmed force fades in over this time.
    pub fade_in_ms: f64,
}

impl Default for GateLimits {
    fn default() -> Self {
        GateLimits {
            sigmas: 4.0,
            min_sigma_deg: 0.02,
            full_sigma_deg: 0.1,
            confirm_frames: 4,
            fade_in_ms: 150.0,
        }
    }
}

impl Default for TeleopGains {
    fn default() -> Self {
        TeleopGains {
            rate_hz: 1000.0,
            deadband_mm: Vector3::repeat(2.0),
            gain_um_per_s_per_mm: Vector3::repeat(1.0),
            speed_limit_um_per_s: Vector3::repeat(20.0),
            stage_from_haptic: Matrix3::identity(),
            spring_n_per_mm: Vector3::repeat(0.05),
            damping_n_s_per_mm: Vector3::repeat(0.0005),
            force_scale_n_per_nn: 2e-4,
            press_direction_stage: Vector3::new(0.0, 0.0, -1.0),
            pressing_force_sign: 1.0,
            max_force_n: 3.0,
            force_rate_n_per_s: 60.0,
            safety: SafetyLimits::default(),
            cantilever: Cantilever::new(
                434.675,
                Cantilever::rigidity_from_spring_constant(0.06, 434.675),
            ),
        }
    }
}

impl Default for SafetyLimits {
    fn default() -> Self {
        SafetyLimits {
            stale_after_ms: 100.0,
            fade_ms: 200.0,
            max_contact_force_nn: 10_000.0,
            recentre_radius_mm: 1.5,
            gate: GateLimits::default(),
            stale_period_margin: 2.0,
            max_frame_period_ms: 250.0,
        }
    }
}

impl TeleopGains {
    /// Period of the haptic loop in microseconds.
    pub fn period_us(&self) -> f64 {
        1e6 / self.rate_hz
    }

    /// Stylus force direction for a stage force direction (orthonormal map, so its transpose).
    pub fn haptic_from_stage(&self) -> Matrix3<f64> {
        self.stage_from_haptic.transpose()
    }

    pub(crate) fn validate(
        teleop: RawTeleop,
        safety: RawSafety,
        check: &Checker,
    ) -> Result<TeleopGains, ConfigError> {
        let d = TeleopGains::default();
        let num = |key: &str, v: Option<f64>, default: f64, range: Range| {
            check.number_or(key, v, default, range)
        };
        let axes = |key: &str, v: Option<List<f64, 3>>, default: Vector3<f64>, range: Range| match v
        {
            Some(List(v)) => check.vector3(key, v, range),
            None => Ok(default),
        };
        let stage_from_haptic = match teleop.stage_from_haptic {
            Some(List(rows)) => check.orthonormal("teleop.stage_from_haptic", rows.map(|r| r.0))?,
            None => d.stage_from_haptic,
        };
        let press_direction_stage = match teleop.press_direction_stage {
            Some(List(v)) => check.unit_vector("teleop.press_direction_stage", v)?,
            None => d.press_direction_stage,
        };
        let pressing_force_sign = match teleop.pressing_force_sign {
            None => d.pressing_force_sign,
            Some(s) if s == 1.0 || s == -1.0 => s,
            Some(s) => {
                return Err(check.invalid("teleop.pressing_force_sign", s, "must be 1 or -1"))
            }
        };
        let s = &d.safety;
        let dg = &s.gate;
        let safety = SafetyLimits {
            stale_after_ms: num(
                "safety.stale_after_ms",
                safety.stale_after_ms,
                s.stale_after_ms,
                STALE_AFTER_MS,
            )?,
            fade_ms: num("safety.fade_ms", safety.fade_ms, s.fade_ms, FADE_MS)?,
            max_contact_force_nn: num(
                "safety.max_contact_force_nn",
                safety.max_contact_force_nn,
                s.max_contact_force_nn,
                CONTACT_FORCE_NN,
            )?,
            recentre_radius_mm: num(
                "safety.recentre_radius_mm",
                safety.recentre_radius_mm,
                s.recentre_radius_mm,
                TRAVEL_MM,
            )?,
            gate: GateLimits {
                sigmas: num(
                    "safety.gate_sigmas",
                    safety.gate_sigmas,
                    dg.sigmas,
                    GATE_SIGMAS,
                )?,
                min_sigma_deg: num(
                    "safety.gate_min_sigma_deg",
                    safety.gate_min_sigma_deg,
                    dg.min_sigma_deg,
                    GATE_MIN_SIGMA_DEG,
                )?,
                full_sigma_deg: num(
                    "safety.gate_full_sigma_deg",
                    safety.gate_full_sigma_deg,
                    dg.full_sigma_deg,
                    GATE_FULL_SIGMA_DEG,
                )?,
                confirm_frames: match safety.gate_confirm_frames {
                    None => dg.confirm_frames,
                    Some(n) => {
                        check.whole("safety.gate_confirm_frames", n, GATE_CONFIRM_FRAMES)? as u32
                    }
                },
                fade_in_ms: num(
                    "safety.gate_fade_in_ms",
                    safety.gate_fade_in_ms,
                    dg.fade_in_ms,
                    FADE_MS,
                )?,
            },
            stale_period_margin: num(
                "safety.stale_period_margin",
                safety.stale_period_margin,
                s.stale_period_margin,
                STALE_PERIOD_MARGIN,
            )?,
            max_frame_period_ms: num(
                "safety.max_frame_period_ms",
                safety.max_frame_period_ms,
                s.max_frame_period_ms,
                MAX_FRAME_PERIOD_MS,
            )?,
        };
        let gains = TeleopGains {
            rate_hz: num("teleop.rate_hz", teleop.rate_hz, d.rate_hz, RATE_HZ)?,
            deadband_mm: axes(
                "teleop.deadband_mm",
                teleop.deadband_mm,
                d.deadband_mm,
                TRAVEL_MM,
            )?,
            gain_um_per_s_per_mm: axes(
                "teleop.gain_um_per_s_per_mm",
                teleop.gain_um_per_s_per_mm,
                d.gain_um_per_s_per_mm,
                GAIN_UM_PER_S_PER_MM,
            )?,
            speed_limit_um_per_s: axes(
                "teleop.speed_limit_um_per_s",
                teleop.speed_limit_um_per_s,
                d.speed_limit_um_per_s,
                SPEED_UM_PER_S,
            )?,
            stage_from_haptic,
            spring_n_per_mm: axes(
                "teleop.spring_n_per_mm",
                teleop.spring_n_per_mm,
                d.spring_n_per_mm,
                SPRING_N_PER_MM,
            )?,
            damping_n_s_per_mm: axes(
                "teleop.damping_n_s_per_mm",
                teleop.damping_n_s_per_mm,
                d.damping_n_s_per_mm,
                DAMPING_N_S_PER_MM,
            )?,
            force_scale_n_per_nn: num(
                "teleop.force_scale_n_per_nn",
                teleop.force_scale_n_per_nn,
                d.force_scale_n_per_nn,
                FORCE_SCALE_N_PER_NN,
            )?,
            press_direction_stage,
            pressing_force_sign,
            max_force_n: num(
                "teleop.max_force_n",
                teleop.max_force_n,
                d.max_force_n,
                STYLUS_FORCE_N,
            )?,
            force_rate_n_per_s: num(
                "teleop.force_rate_n_per_s",
                teleop.force_rate_n_per_s,
                d.force_rate_n_per_s,
                FORCE_RATE_N_PER_S,
            )?,
            safety,
            cantilever: d.cantilever,
        };
        let min_deadband = gains.deadband_mm.min();
        if gains.safety.recentre_radius_mm > min_deadband {
            return Err(check.inconsistent(format!(
                "safety.recentre_radius_mm ({}) must not exceed the smallest teleop.deadband_mm ({}): \
                 re-engaging must never start with a jump in velocity",
                gains.safety.recentre_radius_mm, min_deadband
            )));
        }
        Ok(gains)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use crate::config::Config;

    const CANTILEVER: &str = "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n";

    fn error_of(extra: &str) -> String {
        Config::from_toml_str(&format!("{CANTILEVER}{extra}"), Path::new("lab.toml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn defaults_are_valid_and_documented_values() {
        let cfg = Config::from_toml_str(CANTILEVER, Path::new("lab.toml")).unwrap();
        let defaults = super::TeleopGains {
            cantilever: cfg.probes[0].cantilever.unwrap(),
            ..super::TeleopGains::default()
        };
        assert_eq!(cfg.teleop, defaults);
        assert_eq!(cfg.teleop.period_us(), 1000.0);
    }

    #[test]
    fn axis_map_must_be_orthonormal() {
        let msg = error_of("[teleop]\nstage_from_haptic = [[1, 0, 0], [0, 2, 0], [0, 0, 1]]\n");
        assert!(
            msg.starts_with("lab.toml: teleop.stage_from_haptic must be orthonormal"),
            "{msg}"
        );
        let cfg = Config::from_toml_str(
            &format!(
                "{CANTILEVER}[teleop]\nstage_from_haptic = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]\n"
            ),
            Path::new("lab.toml"),
        )
        .unwrap();
        assert_eq!(cfg.teleop.stage_from_haptic[(0, 1)], -1.0);
    }

    #[test]
    fn bad_values_name_key_and_value() {
        let msg = error_of("[teleop]\ndeadband_mm = [1, -1, 1]\n");
        assert_eq!(
            msg,
            "lab.toml: teleop.deadband_mm[1] = -1 is out of range: accepted 0.1 to 20 mm"
        );
        let msg = error_of("[teleop]\npressing_force_sign = 0\n");
        assert!(
            msg.contains("teleop.pressing_force_sign must be 1 or -1, got 0"),
            "{msg}"
        );
        let msg = error_of("[teleop]\nrate_hz = 50\n");
        assert!(msg.contains("teleop.rate_hz"), "{msg}");
        let msg = error_of("[safety]\nfade_ms = -5\n");
        assert!(
            msg.contains("safety.fade_ms") && msg.contains("-5"),
            "{msg}"
        );
        let msg = error_of("[teleop]\npress_direction_stage = [0, 0, 0]\n");
        assert!(msg.contains("teleop.press_direction_stage"), "{msg}");
        let msg = error_of("[safety]\nstale_ms = 5\n");
        assert!(msg.contains("stale_ms"), "{msg}");
    }

    #[test]
    fn absurd_gains_name_the_accepted_range() {
        assert_eq!(
            error_of("[teleop]\nmax_force_n = 1e9\n"),
            "lab.toml: teleop.max_force_n = 1e9 is out of range: accepted 0.01 to 10 N"
        );
        assert_eq!(
            error_of("[teleop]\nspeed_limit_um_per_s = [20.0, -5.0, 20.0]\n"),
            "lab.toml: teleop.speed_limit_um_per_s[1] = -5 is out of range: \
             accepted 0 to 5000 um/s"
        );
        assert_eq!(
            error_of("[teleop]\nforce_scale_n_per_nn = 0\n"),
            "lab.toml: teleop.force_scale_n_per_nn = 0 is out of range: \
             accepted 1e-8 to 1 N/nN"
        );
        assert_eq!(
            error_of("[safety]\nstale_after_ms = nan\n"),
            "lab.toml: safety.stale_after_ms = nan is out of range: accepted 10 to 2000 ms"
        );
        assert_eq!(
            error_of("[teleop]\nspring_n_per_mm = [inf, 0.05, 0.05]\n"),
            "lab.toml: teleop.spring_n_per_mm[0] = inf is out of range: accepted 0 to 5 N/mm"
        );
    }

    #[test]
    fn lists_of_the_wrong_length_are_refused() {
        for text in [
            "[teleop]\ndeadband_mm = [2.0, 2.0, 2.0, 2.0]\n",
            "[teleop]\nstage_from_haptic = [[1, 0, 0, 5], [0, 1, 0], [0, 0, 1]]\n",
            "[sim.sem]\nmagnification = [[0.0, 3500.0, 1.0]]\n",
        ] {
            let msg = error_of(text);
            assert!(
                msg.starts_with("lab.toml: ") && msg.contains("expected a list of"),
                "{text}: {msg}"
            );
        }
    }

    #[test]
    fn recentre_radius_must_fit_inside_the_deadband() {
        let msg = error_of("[teleop]\ndeadband_mm = [1, 1, 1]\n[safety]\nrecentre_radius_mm = 2\n");
        assert!(msg.contains("safety.recentre_radius_mm (2)"), "{msg}");
    }
}
