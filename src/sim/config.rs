//! `[sim.stage]`, `[sim.sample]`, `[sim.sem]`, `[sim.operator]`: the simulated lab that
//! stands in for the S100, the sample, the SEM and the operator when a device's
//! backend is `"sim"`. Every key is optional; the defaults are in `config/sim.toml`.
use serde::Deserialize;

use super::contact::SampleParams;
use super::operator::OperatorParams;
use super::stage::StageParams;
use crate::checks::{Checker, ConfigError, List, Range};
use crate::scene::{Entry, ToolKind};

// The accepted ranges, documented with the same words in config/sim.toml: a simulated
// lab that stays a lab (an S100-like stage, an SEM, a person's hand).
/// Slower than 1 um/s nothing happens in a run; faster than 5 mm/s no nanomanipulator.
const STAGE_SPEED_UM_PER_S: Range = Range::new(1.0, 5000.0, "um/s");
/// The stage's response time constant.
const STAGE_LAG_MS: Range = Range::new(0.1, 1000.0, "ms");
/// The S100's step is about 5 nm; 0.1 nm to 1 um covers piezo and slip-stick stages.
const STAGE_RESOLUTION_NM: Range = Range::new(0.1, 1000.0, "nm");
/// The S100 travels 12 mm.
const STAGE_WORKSPACE_MM: Range = Range::new(0.1, 100.0, "mm");
const CONTACT_AT_UM: Range = Range::new(0.1, 10_000.0, "um");
/// From soft biological samples (1 mN/m) to hard contacts (10 kN/m).
const SAMPLE_STIFFNESS_N_PER_M: Range = Range::new(0.001, 10_000.0, "N/m");
/// A slow SEM scan (10 s a frame) to a fast camera; the renderer keeps up to 240 Hz.
const SEM_RATE_HZ: Range = Range::new(0.1, 240.0, "Hz");
const SEM_DELAY_MS: Range = Range::new(0.0, 2000.0, "ms");
const SEM_WIDTH_PX: Range = Range::new(320.0, 2048.0, "px");
const SEM_HEIGHT_PX: Range = Range::new(240.0, 2048.0, "px");
/// Where the rendered probe still fits the frame and shows its tip.
const SEM_MAGNIFICATION: Range = Range::new(500.0, 20_000.0, "");
/// Magnification step times: within a day.
const SEM_STEP_S: Range = Range::new(0.0, 86_400.0, "s");
/// Where an apex may sit at first contact, as a fraction of the view's width or height:
/// the probe's tip stays inside the frame.
const APEX_AT: Range = Range::new(0.05, 0.95, "of the view");
/// A positioner's start along the press direction: within the S100's 12 mm travel.
const START_UM: Range = Range::new(0.0, 12_000.0, "um");
/// Stylus travel of a scripted move: a PHANToM's workspace is 70 to 380 mm across.
const OPERATOR_TRAVEL_MM: Range = Range::new(0.1, 200.0, "mm");
/// Felt tip forces, as `safety.max_contact_force_nn`.
const OPERATOR_FORCE_NN: Range = Range::new(1.0, 1e7, "nN");
const OPERATOR_TIME_S: Range = Range::new(0.01, 3600.0, "s");
/// A relaxed to a braced human hand holds a stylus with 0.1 to a few N/mm.
const HAND_STIFFNESS_N_PER_MM: Range = Range::new(0.01, 10.0, "N/mm");
/// A PHANToM stylus's apparent mass is 45 to 75 g.
const STYLUS_MASS_KG: Range = Range::new(0.001, 1.0, "kg");

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSim {
    stage: Option<RawStage>,
    sample: Option<RawSample>,
    sem: Option<RawSem>,
    operator: Option<RawOperator>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStage {
    speed_limit_um_per_s: Option<f64>,
    lag_ms: Option<f64>,
    resolution_nm: Option<f64>,
    workspace_mm: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSample {
    contact_at_um: Option<f64>,
    stiffness_n_per_m: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSem {
    rate_hz: Option<f64>,
    delay_ms: Option<f64>,
    width: Option<i64>,
    height: Option<i64>,
    style: Option<String>,
    seed: Option<u64>,
    magnification: Option<Vec<List<f64, 2>>>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOperator {
    approach_mm: Option<f64>,
    press_mm: Option<f64>,
    retract_mm: Option<f64>,
    touch_nn: Option<f64>,
    target_force_nn: Option<f64>,
    hold_s: Option<f64>,
    retract_s: Option<f64>,
    rest_s: Option<f64>,
    give_up_s: Option<f64>,
    hand_stiffness_n_per_mm: Option<f64>,
    stylus_mass_kg: Option<f64>,
}

/// `[probe.sim]` as written.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSimProbe {
    entry: Option<String>,
    apex_at: Option<List<f64, 2>>,
    start_um: Option<f64>,
    tool: Option<String>,
}

/// One probe in the simulated lab: where the SEM shows it and where its positioner
/// starts (`[probe.sim]` of a `[[probe]]` entry; the lone probe of a file takes the
/// defaults).
#[derive(Debug, Clone, PartialEq)]
pub struct SimProbe {
    /// The side its beam enters the view from.
    pub entry: Entry,
    /// Where its apex sits at first contact, as fractions of the view's width and height.
    pub apex_at: [f64; 2],
    /// Its positioner's start: this far along the press direction, um. First contact is
    /// at `[sim.sample] contact_at_um`; a start past it holds a steady contact.
    pub start_um: f64,
    /// A rigid tool drawn in the cantilever's stead (a probe without `[cantilever]`):
    /// it hangs where `apex_at` puts its tip and moves with its positioner, unbent.
    pub tool: Option<ToolKind>,
}

/// Where the simulated SEM shows a lone probe, and each of several (two face each
/// other mid-frame; a third and fourth add a lower row), by default.
const SINGLE_SLOT: (Entry, [f64; 2]) = (Entry::Left, [0.45, 0.55]);
const SLOTS: [(Entry, [f64; 2]); 4] = [
    (Entry::Left, [0.3, 0.45]),
    (Entry::Right, [0.7, 0.45]),
    (Entry::Left, [0.3, 0.8]),
    (Entry::Right, [0.7, 0.8]),
];

impl SimProbe {
    /// Probe `k` of `count` with `[probe.sim]`'s keys (spelt with `prefix`) over the
    /// defaults of its place.
    pub(crate) fn validate(
        raw: Option<RawSimProbe>,
        prefix: &str,
        k: usize,
        count: usize,
        check: &Checker,
    ) -> Result<SimProbe, ConfigError> {
        let raw = raw.unwrap_or_default();
        let key = |name: &str| format!("{prefix}sim.{name}");
        let (entry, apex_at) = match count {
            1 => SINGLE_SLOT,
            _ => SLOTS[k.min(SLOTS.len() - 1)],
        };
        let entry = match raw.entry.as_deref() {
            None => entry,
            Some("left") => Entry::Left,
            Some("right") => Entry::Right,
            Some(other) => {
                return Err(check.invalid(
                    &key("entry"),
                    format_args!("{other:?}"),
                    "must be \"left\" or \"right\"",
                ))
            }
        };
        let apex_at = match raw.apex_at {
            None => apex_at,
            Some(List([x, y])) => [
                check.number(&format!("{}[0]", key("apex_at")), x, APEX_AT)?,
                check.number(&format!("{}[1]", key("apex_at")), y, APEX_AT)?,
            ],
        };
        let tool = match raw.tool.as_deref() {
            None => None,
            Some(name) => Some(
                ToolKind::ALL
                    .into_iter()
                    .find(|kind| kind.name() == name)
                    .ok_or_else(|| {
                        check.invalid(
                            &key("tool"),
                            format_args!("{name:?}"),
                            "must be \"needle\", \"tipless\" or \"gripper\"",
                        )
                    })?,
            ),
        };
        Ok(SimProbe {
            entry,
            apex_at,
            start_um: check.number_or(&key("start_um"), raw.start_um, 0.0, START_UM)?,
            tool,
        })
    }
}

/// The simulated SEM.
#[derive(Debug, Clone, PartialEq)]
pub struct SemParams {
    pub rate_hz: f64,
    /// From the middle of a frame's scan to the frame being available.
    pub delay_ms: f64,
    pub width: u32,
    pub height: u32,
    /// A scene style preset: "clean", "clutter", "noisy" or "harsh".
    pub style: String,
    pub seed: u64,
    /// (time s, magnification) steps: from each time on, that magnification.
    pub magnification: Vec<(f64, f64)>,
}

impl Default for SemParams {
    fn default() -> Self {
        SemParams {
            rate_hz: 60.0,
            delay_ms: 20.0,
            width: 640,
            height: 480,
            style: "noisy".into(),
            seed: 1,
            magnification: vec![(0.0, 3500.0), (9.0, 2000.0), (18.0, 5000.0), (27.0, 3500.0)],
        }
    }
}

impl SemParams {
    /// The magnification in effect at `t_s`.
    pub fn magnification_at(&self, t_s: f64) -> f64 {
        self.magnification
            .iter()
            .take_while(|(from, _)| *from <= t_s)
            .last()
            .or(self.magnification.first())
            .map_or(2000.0, |(_, m)| *m)
    }
}

/// Validated `[sim]`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimConfig {
    pub stage: StageParams,
    pub sample: SampleParams,
    pub sem: SemParams,
    pub operator: OperatorParams,
}

/// The style presets the renderer knows.
pub const STYLES: [&str; 4] = ["clean", "clutter", "noisy", "harsh"];

impl SimConfig {
    pub(crate) fn validate(raw: RawSim, check: &Checker) -> Result<SimConfig, ConfigError> {
        let d = SimConfig::default();
        let num = |key: &str, v: Option<f64>, default: f64, range: Range| {
            check.number_or(key, v, default, range)
        };
        let st = raw.stage.unwrap_or_default();
        let stage = StageParams {
            speed_limit_um_per_s: num(
                "sim.stage.speed_limit_um_per_s",
                st.speed_limit_um_per_s,
                d.stage.speed_limit_um_per_s,
                STAGE_SPEED_UM_PER_S,
            )?,
            lag_ms: num("sim.stage.lag_ms", st.lag_ms, d.stage.lag_ms, STAGE_LAG_MS)?,
            resolution_nm: num(
                "sim.stage.resolution_nm",
                st.resolution_nm,
                d.stage.resolution_nm,
                STAGE_RESOLUTION_NM,
            )?,
            workspace_mm: num(
                "sim.stage.workspace_mm",
                st.workspace_mm,
                d.stage.workspace_mm,
                STAGE_WORKSPACE_MM,
            )?,
        };
        let sa = raw.sample.unwrap_or_default();
        let sample = SampleParams {
            contact_at_um: num(
                "sim.sample.contact_at_um",
                sa.contact_at_um,
                d.sample.contact_at_um,
                CONTACT_AT_UM,
            )?,
            stiffness_n_per_m: num(
                "sim.sample.stiffness_n_per_m",
                sa.stiffness_n_per_m,
                d.sample.stiffness_n_per_m,
                SAMPLE_STIFFNESS_N_PER_M,
            )?,
        };
        let sem = Self::sem(raw.sem.unwrap_or_default(), check, &d.sem)?;
        let o = raw.operator.unwrap_or_default();
        let od = &d.operator;
        let travel =
            |key: &str, v: Option<f64>, default: f64| num(key, v, default, OPERATOR_TRAVEL_MM);
        let force =
            |key: &str, v: Option<f64>, default: f64| num(key, v, default, OPERATOR_FORCE_NN);
        let time = |key: &str, v: Option<f64>, default: f64| num(key, v, default, OPERATOR_TIME_S);
        let operator = OperatorParams {
            approach_mm: travel("sim.operator.approach_mm", o.approach_mm, od.approach_mm)?,
            press_mm: travel("sim.operator.press_mm", o.press_mm, od.press_mm)?,
            retract_mm: travel("sim.operator.retract_mm", o.retract_mm, od.retract_mm)?,
            touch_nn: force("sim.operator.touch_nn", o.touch_nn, od.touch_nn)?,
            target_force_nn: force(
                "sim.operator.target_force_nn",
                o.target_force_nn,
                od.target_force_nn,
            )?,
            hold_s: time("sim.operator.hold_s", o.hold_s, od.hold_s)?,
            retract_s: time("sim.operator.retract_s", o.retract_s, od.retract_s)?,
            rest_s: time("sim.operator.rest_s", o.rest_s, od.rest_s)?,
            give_up_s: time("sim.operator.give_up_s", o.give_up_s, od.give_up_s)?,
            hand_stiffness_n_per_mm: num(
                "sim.operator.hand_stiffness_n_per_mm",
                o.hand_stiffness_n_per_mm,
                od.hand_stiffness_n_per_mm,
                HAND_STIFFNESS_N_PER_MM,
            )?,
            stylus_mass_kg: num(
                "sim.operator.stylus_mass_kg",
                o.stylus_mass_kg,
                od.stylus_mass_kg,
                STYLUS_MASS_KG,
            )?,
        };
        Ok(SimConfig {
            stage,
            sample,
            sem,
            operator,
        })
    }

    fn sem(raw: RawSem, check: &Checker, d: &SemParams) -> Result<SemParams, ConfigError> {
        let size = |key: &str, v: Option<i64>, default: u32, range: Range| match v {
            None => Ok(default),
            // In range, so it fits.
            Some(v) => check.whole(key, v, range).map(|v| v as u32),
        };
        let style = match raw.style {
            None => d.style.clone(),
            Some(s) if STYLES.contains(&s.as_str()) => s,
            Some(s) => {
                return Err(check.invalid(
                    "sim.sem.style",
                    format_args!("{s:?}"),
                    "must be one of \"clean\", \"clutter\", \"noisy\", \"harsh\"",
                ))
            }
        };
        let magnification = match raw.magnification {
            None => d.magnification.clone(),
            Some(steps) if steps.is_empty() => {
                return Err(check.invalid(
                    "sim.sem.magnification",
                    "[]",
                    "needs at least one [time_s, magnification] step",
                ))
            }
            Some(steps) => {
                let mut out: Vec<(f64, f64)> = Vec::with_capacity(steps.len());
                for (i, List([t, m])) in steps.into_iter().enumerate() {
                    let key = format!("sim.sem.magnification[{i}]");
                    let t = check.number(&format!("{key}[0]"), t, SEM_STEP_S)?;
                    if out.last().is_some_and(|(prev, _)| t < *prev) {
                        return Err(check.invalid(
                            &format!("{key}[0]"),
                            t,
                            "must not be earlier than the step before (times increase)",
                        ));
                    }
                    out.push((t, check.number(&format!("{key}[1]"), m, SEM_MAGNIFICATION)?));
                }
                out
            }
        };
        Ok(SemParams {
            rate_hz: check.number_or("sim.sem.rate_hz", raw.rate_hz, d.rate_hz, SEM_RATE_HZ)?,
            delay_ms: check.number_or(
                "sim.sem.delay_ms",
                raw.delay_ms,
                d.delay_ms,
                SEM_DELAY_MS,
            )?,
            width: size("sim.sem.width", raw.width, d.width, SEM_WIDTH_PX)?,
            height: size("sim.sem.height", raw.height, d.height, SEM_HEIGHT_PX)?,
            style,
            seed: raw.seed.unwrap_or(d.seed),
            magnification,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magnification_steps() {
        let sem = SemParams {
            magnification: vec![(0.0, 3500.0), (5.0, 2000.0)],
            ..SemParams::default()
        };
        assert_eq!(sem.magnification_at(0.0), 3500.0);
        assert_eq!(sem.magnification_at(4.99), 3500.0);
        assert_eq!(sem.magnification_at(5.0), 2000.0);
        assert_eq!(sem.magnification_at(100.0), 2000.0);
    }
}
