//! `[sim.stage]`, `[sim.sample]`, `[sim.sem]`, `[sim.operator]`: the simulated lab that
//! stands in for the S100, the sample, the SEM and the operator when a device's
//! backend is `"sim"`. Every key is optional; the defaults are in `config/sim.toml`.
use serde::Deserialize;

use super::contact::SampleParams;
use super::operator::OperatorParams;
use super::stage::StageParams;
use crate::config::{Checker, ConfigError};

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
    width: Option<u32>,
    height: Option<u32>,
    style: Option<String>,
    seed: Option<u64>,
    magnification: Option<Vec<[f64; 2]>>,
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
    hand_stiffness_n_per_mm: Option<f64>,
    stylus_mass_kg: Option<f64>,
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
        let pos = |key: &str, v: Option<f64>, default: f64| match v {
            Some(v) => check.positive(key, v),
            None => Ok(default),
        };
        let st = raw.stage.unwrap_or_default();
        let stage = StageParams {
            speed_limit_um_per_s: pos(
                "sim.stage.speed_limit_um_per_s",
                st.speed_limit_um_per_s,
                d.stage.speed_limit_um_per_s,
            )?,
            lag_ms: pos("sim.stage.lag_ms", st.lag_ms, d.stage.lag_ms)?,
            resolution_nm: pos(
                "sim.stage.resolution_nm",
                st.resolution_nm,
                d.stage.resolution_nm,
            )?,
            workspace_mm: pos(
                "sim.stage.workspace_mm",
                st.workspace_mm,
                d.stage.workspace_mm,
            )?,
        };
        let sa = raw.sample.unwrap_or_default();
        let sample = SampleParams {
            contact_at_um: pos(
                "sim.sample.contact_at_um",
                sa.contact_at_um,
                d.sample.contact_at_um,
            )?,
            stiffness_n_per_m: pos(
                "sim.sample.stiffness_n_per_m",
                sa.stiffness_n_per_m,
                d.sample.stiffness_n_per_m,
            )?,
        };
        let sem = Self::sem(raw.sem.unwrap_or_default(), check, &d.sem)?;
        let o = raw.operator.unwrap_or_default();
        let od = &d.operator;
        let operator = OperatorParams {
            approach_mm: pos("sim.operator.approach_mm", o.approach_mm, od.approach_mm)?,
            press_mm: pos("sim.operator.press_mm", o.press_mm, od.press_mm)?,
            retract_mm: pos("sim.operator.retract_mm", o.retract_mm, od.retract_mm)?,
            touch_nn: pos("sim.operator.touch_nn", o.touch_nn, od.touch_nn)?,
            target_force_nn: pos(
                "sim.operator.target_force_nn",
                o.target_force_nn,
                od.target_force_nn,
            )?,
            hold_s: pos("sim.operator.hold_s", o.hold_s, od.hold_s)?,
            retract_s: pos("sim.operator.retract_s", o.retract_s, od.retract_s)?,
            rest_s: pos("sim.operator.rest_s", o.rest_s, od.rest_s)?,
            hand_stiffness_n_per_mm: pos(
                "sim.operator.hand_stiffness_n_per_mm",
                o.hand_stiffness_n_per_mm,
                od.hand_stiffness_n_per_mm,
            )?,
            stylus_mass_kg: pos(
                "sim.operator.stylus_mass_kg",
                o.stylus_mass_kg,
                od.stylus_mass_kg,
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
        let pos = |key: &str, v: Option<f64>, default: f64| match v {
            Some(v) => check.positive(key, v),
            None => Ok(default),
        };
        let size = |key: &str, v: Option<u32>, default: u32, range: (u32, u32)| match v {
            None => Ok(default),
            Some(v) if (range.0..=range.1).contains(&v) => Ok(v),
            Some(v) => Err(check.invalid(
                key,
                v,
                &format!("must be in [{}, {}] pixels", range.0, range.1),
            )),
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
        let check_mag = |key: &str, m: f64| {
            if (500.0..=20_000.0).contains(&m) {
                Ok(m)
            } else {
                Err(check.invalid(key, m, "must be a magnification in [500, 20000]"))
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
                let mut out = Vec::with_capacity(steps.len());
                for [t, m] in steps {
                    if !(t.is_finite() && t >= 0.0) || out.last().is_some_and(|(prev, _)| t < *prev)
                    {
                        return Err(check.invalid(
                            "sim.sem.magnification",
                            t,
                            "times must be finite, >= 0 and increasing",
                        ));
                    }
                    out.push((t, check_mag("sim.sem.magnification", m)?));
                }
                out
            }
        };
        let rate_hz = pos("sim.sem.rate_hz", raw.rate_hz, d.rate_hz)?;
        if rate_hz > 240.0 {
            return Err(check.invalid("sim.sem.rate_hz", rate_hz, "must be at most 240 Hz"));
        }
        Ok(SemParams {
            rate_hz,
            delay_ms: match raw.delay_ms {
                Some(v) if v.is_finite() && v >= 0.0 => v,
                Some(v) => {
                    return Err(check.invalid(
                        "sim.sem.delay_ms",
                        v,
                        "must be a finite number >= 0",
                    ))
                }
                None => d.delay_ms,
            },
            width: size("sim.sem.width", raw.width, d.width, (320, 2048))?,
            height: size("sim.sem.height", raw.height, d.height, (240, 2048))?,
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
