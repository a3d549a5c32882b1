//! `[daq]`: what drives the S100 controller's rate inputs. `"sim"` (the simulated
//! stage) or `"comedi"` (a comedi DAQ board). With comedi each stage axis has its own
//! table, `[daq.x]`, `[daq.y]`, `[daq.z]`, choosing its output style:
//!
//! - `output = "analog"`: an analog output channel, `volts_per_um_s` volts per um/s
//!   around `zero_v` (boards with AO: PCI-6035E/6036E, most comedi boards);
//! - `output = "step_dir"`: a general-purpose counter's pulse train sets the speed
//!   (`pulses_per_um`) and a digital line the direction (the PCI-6034E, which has no AO);
//! - `output = "none"`: the axis is not wired; commands on it are never sent.
use std::path::PathBuf;

use serde::Deserialize;

use crate::config::{Checker, ConfigError};
use crate::hw::config::{backend_name, in_range, only_for, required, DaqBackend};

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDaq {
    backend: Option<String>,
    device: Option<String>,
    x: Option<RawAxis>,
    y: Option<RawAxis>,
    z: Option<RawAxis>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAxis {
    output: Option<String>,
    device: Option<String>,
    subdevice: Option<i64>,
    channel: Option<i64>,
    range: Option<i64>,
    range_v: Option<[f64; 2]>,
    volts_per_um_s: Option<f64>,
    zero_v: Option<f64>,
    counter_subdevice: Option<i64>,
    dio_subdevice: Option<i64>,
    direction_channel: Option<i64>,
    pulses_per_um: Option<f64>,
    max_rate_hz: Option<f64>,
    invert_direction: Option<bool>,
}

/// Validated `[daq]` of `backend = "comedi"`.
#[derive(Debug, Clone, PartialEq)]
pub struct ComediConfig {
    pub device: PathBuf,
    /// Stage axes x, y, z.
    pub axes: [AxisOutput; 3],
    /// The board of each axis: `daq.<axis>.device`, else `daq.device` (a PCI-6034E has
    /// two counters, so a third step/direction axis needs a second board).
    pub axis_devices: [PathBuf; 3],
}

/// How one stage axis is driven.
#[derive(Debug, Clone, PartialEq)]
pub enum AxisOutput {
    None,
    Analog(AnalogAxis),
    StepDir(StepDirAxis),
}

/// Which range of an analog output channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeChoice {
    /// Index into the channel's range table.
    Index(u32),
    /// The range that holds `[min_v, max_v]` (`comedi_find_range`).
    Volts { min_v: f64, max_v: f64 },
}

#[derive(Debug, Clone, PartialEq)]
pub struct AnalogAxis {
    pub subdevice: u32,
    pub channel: u32,
    pub range: RangeChoice,
    /// Output volts per um/s of stage speed (sign: the controller's polarity).
    pub volts_per_um_s: f64,
    /// The voltage that commands no motion.
    pub zero_v: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct StepDirAxis {
    /// The NI general-purpose counter generating the pulse train (its output pin).
    pub counter_subdevice: u32,
    pub dio_subdevice: u32,
    pub direction_channel: u32,
    /// Controller steps (pulses) per micrometre of travel.
    pub pulses_per_um: f64,
    /// Fastest pulse train the controller accepts.
    pub max_rate_hz: f64,
    /// Direction line low (instead of high) for positive motion.
    pub invert_direction: bool,
}

impl RawDaq {
    pub(crate) fn validate(self, check: &Checker) -> Result<DaqBackend, ConfigError> {
        let backend = backend_name(check, "daq", &self.backend, &["sim", "comedi"])?;
        if backend == "sim" {
            let keys = [
                ("device", self.device.is_some()),
                ("x", self.x.is_some()),
                ("y", self.y.is_some()),
                ("z", self.z.is_some()),
            ];
            only_for(check, "daq", "daq.backend = \"sim\"", &keys)?;
            return Ok(DaqBackend::Sim);
        }
        let device = PathBuf::from(self.device.unwrap_or_else(|| "/dev/comedi0".into()));
        let axes = [("x", self.x), ("y", self.y), ("z", self.z)];
        let mut out = [AxisOutput::None, AxisOutput::None, AxisOutput::None];
        let mut axis_devices = [device.clone(), device.clone(), device.clone()];
        for ((slot, board), (name, raw)) in out.iter_mut().zip(&mut axis_devices).zip(axes) {
            let key = format!("daq.{name}");
            let raw = required(check, &format!("[{key}]"), backend, raw)?;
            if let Some(d) = &raw.device {
                if d.trim().is_empty() {
                    return Err(check.invalid(
                        &format!("{key}.device"),
                        "\"\"",
                        "must name a device",
                    ));
                }
                *board = PathBuf::from(d);
            }
            *slot = raw.validate(check, &key)?;
        }
        if out.iter().all(|a| *a == AxisOutput::None) {
            return Err(check.inconsistent("daq: every axis has output = \"none\"".into()));
        }
        Ok(DaqBackend::Comedi(Box::new(ComediConfig {
            device,
            axes: out,
            axis_devices,
        })))
    }
}

impl RawAxis {
    fn validate(self, check: &Checker, key: &str) -> Result<AxisOutput, ConfigError> {
        let k = |name: &str| format!("{key}.{name}");
        let analog_keys = [
            ("subdevice", self.subdevice.is_some()),
            ("channel", self.channel.is_some()),
            ("range", self.range.is_some()),
            ("range_v", self.range_v.is_some()),
            ("volts_per_um_s", self.volts_per_um_s.is_some()),
            ("zero_v", self.zero_v.is_some()),
        ];
        let step_keys = [
            ("counter_subdevice", self.counter_subdevice.is_some()),
            ("dio_subdevice", self.dio_subdevice.is_some()),
            ("direction_channel", self.direction_channel.is_some()),
            ("pulses_per_um", self.pulses_per_um.is_some()),
            ("max_rate_hz", self.max_rate_hz.is_some()),
            ("invert_direction", self.invert_direction.is_some()),
        ];
        let subdevice = |v: Option<i64>, name: &str| -> Result<u32, ConfigError> {
            let v = required(check, &k(name), "comedi", v)?;
            in_range(check, &k(name), v, 0, 255)
        };
        match self.output.as_deref() {
            Some("analog") => {
                only_for(check, key, "output = \"analog\"", &step_keys)?;
                let range = match (self.range, self.range_v) {
                    (Some(_), Some(_)) => {
                        return Err(check.inconsistent(format!(
                            "{key}: give range (an index) or range_v ([min, max] volts), not both"
                        )))
                    }
                    (Some(i), None) => RangeChoice::Index(in_range(check, &k("range"), i, 0, 255)?),
                    (None, Some([min_v, max_v])) if min_v.is_finite() && max_v > min_v => {
                        RangeChoice::Volts { min_v, max_v }
                    }
                    (None, Some(v)) => {
                        return Err(check.invalid(
                            &k("range_v"),
                            format_args!("{v:?}"),
                            "must be [min, max] volts with min < max",
                        ))
                    }
                    (None, None) => RangeChoice::Volts {
                        min_v: -10.0,
                        max_v: 10.0,
                    },
                };
                let volts = required(check, &k("volts_per_um_s"), "comedi", self.volts_per_um_s)?;
                if !(volts.is_finite() && volts != 0.0) {
                    let reason = "must be a finite, non-zero number";
                    return Err(check.invalid(&k("volts_per_um_s"), volts, reason));
                }
                let zero_v = self.zero_v.unwrap_or(0.0);
                if !zero_v.is_finite() {
                    return Err(check.invalid(&k("zero_v"), zero_v, "must be finite"));
                }
                Ok(AxisOutput::Analog(AnalogAxis {
                    subdevice: subdevice(self.subdevice, "subdevice")?,
                    channel: subdevice(self.channel, "channel")?,
                    range,
                    volts_per_um_s: volts,
                    zero_v,
                }))
            }
            Some("step_dir") => {
                only_for(check, key, "output = \"step_dir\"", &analog_keys)?;
                let pulses = required(check, &k("pulses_per_um"), "comedi", self.pulses_per_um)?;
                let max_rate_hz = self.max_rate_hz.unwrap_or(100_000.0);
                if !(max_rate_hz.is_finite() && max_rate_hz > 0.0 && max_rate_hz <= 5e6) {
                    let reason = "must be in (0, 5e6] Hz";
                    return Err(check.invalid(&k("max_rate_hz"), max_rate_hz, reason));
                }
                Ok(AxisOutput::StepDir(StepDirAxis {
                    counter_subdevice: subdevice(self.counter_subdevice, "counter_subdevice")?,
                    dio_subdevice: subdevice(self.dio_subdevice, "dio_subdevice")?,
                    direction_channel: subdevice(self.direction_channel, "direction_channel")?,
                    pulses_per_um: check.positive(&k("pulses_per_um"), pulses)?,
                    max_rate_hz,
                    invert_direction: self.invert_direction.unwrap_or(false),
                }))
            }
            Some("none") => {
                only_for(check, key, "output = \"none\"", &analog_keys)?;
                only_for(check, key, "output = \"none\"", &step_keys)?;
                Ok(AxisOutput::None)
            }
            other => Err(check.invalid(
                &k("output"),
                format_args!("{other:?}"),
                "must be \"analog\", \"step_dir\" or \"none\"",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::hw::config::tests::{error_of, parse};
    use crate::hw::config::DaqBackend;
    use crate::hw::daq::config::*;

    const AXES: &str = "[daq.x]\noutput = \"analog\"\nsubdevice = 1\nchannel = 0\n\
                        volts_per_um_s = 0.1\n\
                        [daq.y]\noutput = \"step_dir\"\ncounter_subdevice = 11\n\
                        dio_subdevice = 2\ndirection_channel = 1\npulses_per_um = 50\n\
                        [daq.z]\noutput = \"none\"\n";

    #[test]
    fn both_output_styles() {
        let cfg = parse(&format!("[daq]\nbackend = \"comedi\"\n{AXES}")).unwrap();
        let DaqBackend::Comedi(c) = cfg.devices.daq else {
            panic!("not comedi")
        };
        assert_eq!(c.device, PathBuf::from("/dev/comedi0"));
        let AxisOutput::Analog(x) = &c.axes[0] else {
            panic!("x not analog")
        };
        assert_eq!(
            x.range,
            RangeChoice::Volts {
                min_v: -10.0,
                max_v: 10.0
            }
        );
        assert_eq!((x.subdevice, x.channel, x.zero_v), (1, 0, 0.0));
        let AxisOutput::StepDir(y) = &c.axes[1] else {
            panic!("y not step_dir")
        };
        assert_eq!((y.counter_subdevice, y.direction_channel), (11, 1));
        assert_eq!((y.pulses_per_um, y.max_rate_hz), (50.0, 100_000.0));
        assert_eq!(c.axes[2], AxisOutput::None);
        assert_eq!(c.axis_devices[1], PathBuf::from("/dev/comedi0"));
        let second = AXES.replace("[daq.y]\n", "[daq.y]\ndevice = \"/dev/comedi1\"\n");
        let cfg = parse(&format!("[daq]\nbackend = \"comedi\"\n{second}")).unwrap();
        let DaqBackend::Comedi(c) = cfg.devices.daq else {
            panic!("not comedi")
        };
        assert_eq!(
            c.axis_devices.map(|d| d.display().to_string()),
            ["/dev/comedi0", "/dev/comedi1", "/dev/comedi0"]
        );
    }

    #[test]
    fn axis_errors_name_key_and_value() {
        let base = "[daq]\nbackend = \"comedi\"\n";
        assert!(error_of(base).contains("missing [daq.x]"));
        let msg = error_of(&format!("{base}{}", AXES.replace("0.1", "0")));
        assert_eq!(
            msg,
            "lab.toml: daq.x.volts_per_um_s must be a finite, non-zero number, got 0"
        );
        let msg = error_of(&format!("{base}{}", AXES.replace("\"none\"", "\"pwm\"")));
        assert!(
            msg.contains("daq.z.output must be") && msg.contains("\"pwm\""),
            "{msg}"
        );
        let msg = error_of(&format!(
            "{base}{}",
            AXES.replace("channel = 0", "range = 1\nchannel = 300")
        ));
        assert_eq!(msg, "lab.toml: daq.x.channel must be in 0..=255, got 300");
        let msg = error_of(&format!(
            "{base}{}",
            AXES.replace("pulses_per_um = 50", "zero_v = 1.0")
        ));
        assert_eq!(
            msg,
            "lab.toml: daq.y.zero_v is not used by output = \"step_dir\""
        );
    }
}
