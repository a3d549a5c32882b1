//! `[frames]`, `[daq]`, `[haptic]`: which backend drives each device kind, and its
//! settings. The default for every kind is `"sim"`, the simulated lab, so a
//! configuration that names no hardware never touches any.
//!
//! Each section is read as a TOML table here and then (`tagged`) into its raw enum,
//! tagged by `backend`: each variant holds the backend's own struct of keys
//! (`deny_unknown_fields`), so the backend chosen decides which keys exist, and a key
//! of another backend is an error that lists the chosen one's. `[daq.<axis>]` tables
//! are tagged the same way by `output`. `src/config/mod.rs` needs to know nothing
//! about backends.
//! Keys are validated in every build; whether the backend's cargo feature is compiled
//! in is checked when the devices are opened ([`super::open::check_compiled`]), so a
//! configuration can be checked anywhere.
pub use super::daq::config::DaqBackend;
use super::daq::config::OutputLine;
pub use super::frames::config::FramesBackend;
use super::frames::config::RawFrames;
pub use super::haptic::config::HapticBackend;
use super::haptic::config::RawHaptic;
use crate::checks::{tagged, Checker, ConfigError};

/// One device section, as written in the file.
pub(crate) type RawDevice = toml::Table;

/// Validated device selection.
#[derive(Debug, Clone, PartialEq)]
pub struct DevicesConfig {
    pub frames: FramesBackend,
    /// The S100 positioners, one per probe in view (the probe's order): the DAQ
    /// outputs that drive each.
    pub positioners: Vec<Positioner>,
    pub haptic: HapticBackend,
}

/// One S100 positioner and the DAQ outputs that drive it.
#[derive(Debug, Clone, PartialEq)]
pub struct Positioner {
    /// The section it was read from, as messages name it: `daq`, or `probe[i].daq`.
    pub section: String,
    pub daq: DaqBackend,
}

impl Default for DevicesConfig {
    fn default() -> Self {
        DevicesConfig {
            frames: FramesBackend::Sim,
            positioners: vec![Positioner {
                section: "daq".into(),
                daq: DaqBackend::Sim,
            }],
            haptic: HapticBackend::Sim,
        }
    }
}

impl DevicesConfig {
    /// True when every device is simulated (the built-in lab).
    pub fn all_simulated(&self) -> bool {
        self.frames == FramesBackend::Sim
            && self.haptic == HapticBackend::Sim
            && self.positioners.iter().all(|p| p.daq == DaqBackend::Sim)
    }

    /// `positioners`: each probe's DAQ section as written, with its section name.
    pub(crate) fn validate(
        frames: RawDevice,
        positioners: Vec<(String, RawDevice)>,
        haptic: RawDevice,
        check: &Checker,
    ) -> Result<DevicesConfig, ConfigError> {
        let frames: RawFrames = tagged(check, "frames", "backend", Some("sim"), frames)?;
        let haptic: RawHaptic = tagged(check, "haptic", "backend", Some("sim"), haptic)?;
        let positioners = positioners
            .into_iter()
            .map(|(section, table)| {
                Ok(Positioner {
                    daq: DaqBackend::validate(check, &section, table)?,
                    section,
                })
            })
            .collect::<Result<Vec<_>, ConfigError>>()?;
        one_axis_per_line(&positioners, check)?;
        Ok(DevicesConfig {
            frames: frames.validate(check)?,
            positioners,
            haptic: haptic.validate(check)?,
        })
    }
}

/// No output line drives two axes (of one positioner or of two): their commands would
/// fight over it.
fn one_axis_per_line(positioners: &[Positioner], check: &Checker) -> Result<(), ConfigError> {
    let mut seen: Vec<(String, OutputLine)> = Vec::new();
    for p in positioners {
        let DaqBackend::Comedi(c) = &p.daq else {
            continue;
        };
        for (axis, line) in c.lines() {
            let key = format!("{}.{axis}", p.section);
            if let Some((first, _)) = seen.iter().find(|(_, l)| *l == line) {
                return Err(check.inconsistent(format!(
                    "{key} and {first} drive the same output ({} subdevice {} channel {}): \
                     each axis needs its own",
                    line.board.display(),
                    line.subdevice,
                    line.channel
                )));
            }
            seen.push((key, line));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::config::testing::{error_of, parse};

    #[test]
    fn sim_is_the_default() {
        assert!(parse("").unwrap().devices.all_simulated());
        assert!(parse("[frames]\nbackend = \"sim\"\n[daq]\n[haptic]\n")
            .unwrap()
            .devices
            .all_simulated());
    }

    #[test]
    fn unknown_backend_and_key_are_named() {
        assert_eq!(
            error_of("[frames]\nbackend = \"usb\"\n"),
            "lab.toml: frames.backend = \"usb\" is not one of: sim, v4l2, pipe"
        );
        let msg = error_of("[daq]\nbackend = \"comedi\"\ndevise = \"/dev/comedi0\"\n");
        assert_eq!(
            msg,
            "lab.toml: daq.devise is not a key of daq.backend = \"comedi\" \
             (its keys: device, x, y, z)"
        );
        // A value of the wrong type is named with its section.
        let msg = error_of("[frames]\nbackend = \"v4l2\"\nwidth = \"wide\"\n");
        assert!(msg.starts_with("lab.toml: [frames]: invalid type"), "{msg}");
        let msg = error_of("[frames]\nbackend = 3\n");
        assert!(msg.starts_with("lab.toml: [frames]: invalid type"), "{msg}");
        let msg = error_of("[frames]\ndevice = \"/dev/video0\"\n");
        assert_eq!(
            msg,
            "lab.toml: frames.device is not a key of frames.backend = \"sim\", which has none"
        );
    }
}
