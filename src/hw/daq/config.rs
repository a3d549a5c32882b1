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

use crate::checks::{in_range, required, tagged, NoKeys};
use crate::checks::{Checker, ConfigError, List, Range};

// The accepted ranges, documented with the same words in config/lab.example.toml.
/// DAQ analog outputs span at most +-10 V (a few boards +-20 V).
const VOLTS: Range = Range::new(-20.0, 20.0, "V");
/// 10 V per um/s saturates a +-10 V output at 1 um/s; below 1e-4 V per um/s the full
/// output would command 0.1 m/s. 0 would never move the axis.
const VOLTS_PER_UM_S: Range = Range::new(-10.0, 10.0, "V per um/s").except_zero();
/// From a 100 um step to a 0.1 nm step, finer than any stage resolves.
const PULSES_PER_UM: Range = Range::new(0.01, 10_000.0, "pulses/um");
/// An NI E-series counter divides a 20 MHz timebase: 5 MHz is the fastest usable train.
const MAX_RATE_HZ: Range = Range::new(1.0, 5e6, "Hz");

/// What drives the S100's rate inputs.
#[derive(Debug, Clone, PartialEq)]
pub enum DaqBackend {
    Sim,
    Comedi(Box<ComediConfig>),
}

/// `[daq]` as written: `backend` selects the keys that exist.
#[derive(Debug, Deserialize)]
#[serde(tag = "backend", rename_all = "lowercase")]
enum RawDaq {
    Sim(NoKeys),
    Comedi(Box<RawComedi>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawComedi {
    device: Option<String>,
    /// Each axis's table, read as a [`RawAxis`] in [`RawComedi::validate`] so that
    /// errors name the axis.
    x: Option<toml::Table>,
    y: Option<toml::Table>,
    z: Option<toml::Table>,
}

/// `[daq.<axis>]` as written: `output` selects the keys that exist.
#[derive(Debug, Deserialize)]
#[serde(tag = "output", rename_all = "snake_case")]
enum RawAxis {
    Analog(RawAnalog),
    StepDir(RawStepDir),
    None(NoKeys),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAnalog {
    device: Option<String>,
    subdevice: Option<i64>,
    channel: Option<i64>,
    range: Option<i64>,
    range_v: Option<List<f64, 2>>,
    volts_per_um_s: Option<f64>,
    zero_v: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStepDir {
    device: Option<String>,
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

/// One physical output line of a board: an analog channel, a counter, or a digital
/// line, by board, subdevice and channel (0 for a counter).
#[derive(Debug, Clone, PartialEq)]
pub struct OutputLine {
    pub board: PathBuf,
    pub subdevice: u32,
    pub channel: u32,
}

impl ComediConfig {
    /// Each output line the axes drive, with its axis's name (`x`, `y`, `z`).
    pub fn lines(&self) -> Vec<(&'static str, OutputLine)> {
        let names = ["x", "y", "z"];
        let mut lines = Vec::new();
        for ((axis, board), name) in self.axes.iter().zip(&self.axis_devices).zip(names) {
            let line = |subdevice, channel| OutputLine {
                board: board.clone(),
                subdevice,
                channel,
            };
            match axis {
                AxisOutput::None => {}
                AxisOutput::Analog(a) => lines.push((name, line(a.subdevice, a.channel))),
                AxisOutput::StepDir(s) => {
                    lines.push((name, line(s.counter_subdevice, 0)));
                    lines.push((name, line(s.dio_subdevice, s.direction_channel)));
                }
            }
        }
        lines
    }
}

impl DaqBackend {
    /// Reads and validates a DAQ section as written: `section` names it in messages
    /// (`daq` for the lab's one positioner, `probe[1].daq` for an entry's).
    pub(crate) fn validate(
        check: &Checker,
        section: &str,
        table: toml::Table,
    ) -> Result<DaqBackend, ConfigError> {
        match tagged(check, section, "backend", Some("sim"), table)? {
            RawDaq::Sim(NoKeys {}) => Ok(DaqBackend::Sim),
            RawDaq::Comedi(raw) => raw
                .validate(check, section)
                .map(|c| DaqBackend::Comedi(Box::new(c))),
        }
    }
}

impl RawComedi {
    fn validate(self, check: &Checker, section: &str) -> Result<ComediConfig, ConfigError> {
        let device = PathBuf::from(self.device.unwrap_or_else(|| "/dev/comedi0".into()));
        let axes = [("x", self.x), ("y", self.y), ("z", self.z)];
        let mut out = [AxisOutput::None, AxisOutput::None, AxisOutput::None];
        let mut axis_devices = [device.clone(), device.clone(), device.clone()];
        for ((slot, board), (name, table)) in out.iter_mut().zip(&mut axis_devices).zip(axes) {
            let key = format!("{section}.{name}");
            let table = required(check, &format!("[{key}]"), "comedi", table)?;
            let raw: RawAxis = tagged(check, &key, "output", None, table)?;
            if let Some(d) = raw.device() {
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
            return Err(check.inconsistent(format!("{section}: every axis has output = \"none\"")));
        }
        Ok(ComediConfig {
            device,
            axes: out,
            axis_devices,
        })
    }
}

impl RawAxis {
    /// The axis's own board, when it names one.
    fn device(&self) -> Option<&str> {
        match self {
            RawAxis::Analog(a) => a.device.as_deref(),
            RawAxis::StepDir(s) => s.device.as_deref(),
            RawAxis::None(NoKeys {}) => None,
        }
    }

    fn validate(self, check: &Checker, key: &str) -> Result<AxisOutput, ConfigError> {
        let k = |name: &str| format!("{key}.{name}");
        let subdevice = |v: Option<i64>, name: &str| -> Result<u32, ConfigError> {
            let v = required(check, &k(name), "comedi", v)?;
            in_range(check, &k(name), v, (0, 255), "")
        };
        match self {
            RawAxis::Analog(a) => {
                let range = match (a.range, a.range_v) {
                    (Some(_), Some(_)) => {
                        return Err(check.inconsistent(format!(
                            "{key}: give range (an index) or range_v ([min, max] volts), not both"
                        )))
                    }
                    (Some(i), None) => {
                        RangeChoice::Index(in_range(check, &k("range"), i, (0, 255), "")?)
                    }
                    (None, Some(List([min_v, max_v]))) => {
                        let min_v = check.number(&format!("{key}.range_v[0]"), min_v, VOLTS)?;
                        let max_v = check.number(&format!("{key}.range_v[1]"), max_v, VOLTS)?;
                        if max_v <= min_v {
                            return Err(check.invalid(
                                &k("range_v"),
                                format_args!("{:?}", [min_v, max_v]),
                                "must be [min, max] volts with min < max",
                            ));
                        }
                        RangeChoice::Volts { min_v, max_v }
                    }
                    (None, None) => RangeChoice::Volts {
                        min_v: -10.0,
                        max_v: 10.0,
                    },
                };
                let volts = required(check, &k("volts_per_um_s"), "comedi", a.volts_per_um_s)?;
                let volts = check.number(&k("volts_per_um_s"), volts, VOLTS_PER_UM_S)?;
                let zero_v = check.number_or(&k("zero_v"), a.zero_v, 0.0, VOLTS)?;
                Ok(AxisOutput::Analog(AnalogAxis {
                    subdevice: subdevice(a.subdevice, "subdevice")?,
                    channel: subdevice(a.channel, "channel")?,
                    range,
                    volts_per_um_s: volts,
                    zero_v,
                }))
            }
            RawAxis::StepDir(s) => {
                let pulses = required(check, &k("pulses_per_um"), "comedi", s.pulses_per_um)?;
                let max_rate_hz =
                    check.number_or(&k("max_rate_hz"), s.max_rate_hz, 100_000.0, MAX_RATE_HZ)?;
                Ok(AxisOutput::StepDir(StepDirAxis {
                    counter_subdevice: subdevice(s.counter_subdevice, "counter_subdevice")?,
                    dio_subdevice: subdevice(s.dio_subdevice, "dio_subdevice")?,
                    direction_channel: subdevice(s.direction_channel, "direction_channel")?,
                    pulses_per_um: check.number(&k("pulses_per_um"), pulses, PULSES_PER_UM)?,
                    max_rate_hz,
                    invert_direction: s.invert_direction.unwrap_or(false),
                }))
            }
            RawAxis::None(NoKeys {}) => Ok(AxisOutput::None),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::config::testing::{error_of, parse};
    use crate::hw::daq::config::*;

    const AXES: &str = "[daq.x]\noutput = \"analog\"\nsubdevice = 1\nchannel = 0\n\
                        volts_per_um_s = 0.1\n\
                        [daq.y]\noutput = \"step_dir\"\ncounter_subdevice = 11\n\
                        dio_subdevice = 2\ndirection_channel = 1\npulses_per_um = 50\n\
                        [daq.z]\noutput = \"none\"\n";

    #[test]
    fn both_output_styles() {
        let cfg = parse(&format!("[daq]\nbackend = \"comedi\"\n{AXES}")).unwrap();
        let DaqBackend::Comedi(c) = &cfg.devices.positioners[0].daq else {
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
        let DaqBackend::Comedi(c) = &cfg.devices.positioners[0].daq else {
            panic!("not comedi")
        };
        assert_eq!(
            c.axis_devices.clone().map(|d| d.display().to_string()),
            ["/dev/comedi0", "/dev/comedi1", "/dev/comedi0"]
        );
    }

    #[test]
    fn axis_errors_name_key_and_value() {
        let base = "[daq]\nbackend = \"comedi\"\n";
        assert!(error_of(base).contains("missing [daq.x]"));
        // (what of AXES is replaced, by what, the message)
        for (from, to, message) in [
            (
                "0.1",
                "0",
                "lab.toml: daq.x.volts_per_um_s = 0 is out of range: \
                 accepted -10 to 10 V per um/s, not 0",
            ),
            (
                "\"none\"",
                "\"pwm\"",
                "lab.toml: daq.z.output = \"pwm\" is not one of: analog, step_dir, none",
            ),
            (
                "output = \"none\"\n",
                "",
                "lab.toml: missing daq.z.output (one of: analog, step_dir, none)",
            ),
            (
                "channel = 0",
                "range = 1\nchannel = 300",
                "lab.toml: daq.x.channel = 300 is out of range: accepted 0 to 255",
            ),
            (
                "pulses_per_um = 50",
                "zero_v = 1.0",
                "lab.toml: daq.y.zero_v is not a key of daq.y.output = \"step_dir\" (its keys: \
                 device, counter_subdevice, dio_subdevice, direction_channel, pulses_per_um, \
                 max_rate_hz, invert_direction)",
            ),
        ] {
            assert_eq!(
                error_of(&format!("{base}{}", AXES.replace(from, to))),
                message
            );
        }
    }
}
