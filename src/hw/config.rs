//! `[frames]`, `[daq]`, `[haptic]`: which backend drives each device kind, and its
//! settings. The default for every kind is `"sim"`, the simulated lab, so a
//! configuration that names no hardware never touches any.
//!
//! Each section is read as a TOML table here and then into the backend's own raw struct
//! (`deny_unknown_fields`), so `src/config/mod.rs` needs to know nothing about backends.
//! Keys are validated in every build; whether the backend's cargo feature is compiled
//! in is checked when the devices are opened ([`super::open::check_compiled`]), so a
//! configuration can be checked anywhere.
use serde::de::DeserializeOwned;

use super::daq::config::{ComediConfig, RawDaq};
use super::frames::config::{PipeConfig, RawFrames, V4l2Config};
use super::haptic::config::{HidConfig, OpenHapticsConfig, RawHaptic};
use crate::checks::{Checker, ConfigError, Range};

/// One device section, as written in the file.
pub(crate) type RawDevice = toml::Table;

/// Where frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum FramesBackend {
    Sim,
    V4l2(V4l2Config),
    Pipe(PipeConfig),
}

/// What drives the S100's rate inputs.
#[derive(Debug, Clone, PartialEq)]
pub enum DaqBackend {
    Sim,
    Comedi(Box<ComediConfig>),
}

/// The operator's device.
#[derive(Debug, Clone, PartialEq)]
pub enum HapticBackend {
    Sim,
    OpenHaptics(OpenHapticsConfig),
    Hid(HidConfig),
}

/// Validated device selection.
#[derive(Debug, Clone, PartialEq)]
pub struct DevicesConfig {
    pub frames: FramesBackend,
    pub daq: DaqBackend,
    pub haptic: HapticBackend,
}

impl Default for DevicesConfig {
    fn default() -> Self {
        DevicesConfig {
            frames: FramesBackend::Sim,
            daq: DaqBackend::Sim,
            haptic: HapticBackend::Sim,
        }
    }
}

impl DevicesConfig {
    /// True when every device is simulated (the built-in lab).
    pub fn all_simulated(&self) -> bool {
        *self == DevicesConfig::default()
    }

    pub(crate) fn validate(
        frames: RawDevice,
        daq: RawDevice,
        haptic: RawDevice,
        check: &Checker,
    ) -> Result<DevicesConfig, ConfigError> {
        let frames: RawFrames = section(check, "frames", frames)?;
        let daq: RawDaq = section(check, "daq", daq)?;
        let haptic: RawHaptic = section(check, "haptic", haptic)?;
        Ok(DevicesConfig {
            frames: frames.validate(check)?,
            daq: daq.validate(check)?,
            haptic: haptic.validate(check)?,
        })
    }
}

/// Reads a section table into its raw struct; errors name the section.
fn section<T: DeserializeOwned>(
    check: &Checker,
    name: &str,
    table: RawDevice,
) -> Result<T, ConfigError> {
    toml::Value::Table(table)
        .try_into()
        .map_err(|e: toml::de::Error| check.inconsistent(format!("[{name}]: {}", e.message())))
}

/// The backend name of a section, checked against the known ones.
pub(crate) fn backend_name<'a>(
    check: &Checker,
    section: &str,
    name: &'a Option<String>,
    known: &[&str],
) -> Result<&'a str, ConfigError> {
    match name.as_deref() {
        None => Ok("sim"),
        Some(name) if known.contains(&name) => Ok(name),
        Some(name) => Err(check.invalid(
            &format!("{section}.backend"),
            format_args!("{name:?}"),
            &format!("must be one of {known:?}"),
        )),
    }
}

/// Rejects keys that the chosen option does not use (`present`: key name, whether set;
/// `chosen`: `"frames.backend = \"v4l2\""`).
pub(crate) fn only_for(
    check: &Checker,
    section: &str,
    chosen: &str,
    present: &[(&str, bool)],
) -> Result<(), ConfigError> {
    match present.iter().find(|(_, set)| *set) {
        Some((key, _)) => {
            Err(check.inconsistent(format!("{section}.{key} is not used by {chosen}")))
        }
        None => Ok(()),
    }
}

/// A required key of a backend.
pub(crate) fn required<T>(
    check: &Checker,
    key: &str,
    backend: &str,
    value: Option<T>,
) -> Result<T, ConfigError> {
    value
        .ok_or_else(|| check.inconsistent(format!("missing {key} (needed by backend {backend:?})")))
}

/// A whole number in `lo..=hi` (`unit` as the message prints it, empty for a count).
pub(crate) fn in_range(
    check: &Checker,
    key: &str,
    value: i64,
    (lo, hi): (i64, i64),
    unit: &'static str,
) -> Result<u32, ConfigError> {
    // In range, so it fits (every `hi` in use is below 2^32).
    let range = Range::new(lo as f64, hi as f64, unit);
    check.whole(key, value, range).map(|v| v as u32)
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
            "lab.toml: frames.backend must be one of [\"sim\", \"v4l2\", \"pipe\"], got \"usb\""
        );
        let msg = error_of("[daq]\nbackend = \"comedi\"\ndevise = \"/dev/comedi0\"\n");
        assert!(
            msg.starts_with("lab.toml: [daq]: unknown field `devise`"),
            "{msg}"
        );
        let msg = error_of("[frames]\ndevice = \"/dev/video0\"\n");
        assert_eq!(
            msg,
            "lab.toml: frames.device is not used by frames.backend = \"sim\""
        );
    }
}
