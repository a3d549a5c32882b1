//! `[frames]`, `[daq]`, `[haptic]`: which backend drives each device kind, and its
//! settings. The default for every kind is `"sim"`, the simulated lab, so a
//! configuration that names no hardware never touches any.
//!
//! Each section is read as a TOML table here and then ([`tagged`]) into its raw enum,
//! tagged by `backend`: each variant holds the backend's own struct of keys
//! (`deny_unknown_fields`), so the backend chosen decides which keys exist, and a key
//! of another backend is an error that lists the chosen one's. `[daq.<axis>]` tables
//! are tagged the same way by `output`. `src/config/mod.rs` needs to know nothing
//! about backends.
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
        let frames: RawFrames = tagged(check, "frames", "backend", Some("sim"), frames)?;
        let daq: RawDaq = tagged(check, "daq", "backend", Some("sim"), daq)?;
        let haptic: RawHaptic = tagged(check, "haptic", "backend", Some("sim"), haptic)?;
        Ok(DevicesConfig {
            frames: frames.validate(check)?,
            daq: daq.validate(check)?,
            haptic: haptic.validate(check)?,
        })
    }
}

/// The keys of a choice that has none (`backend = "sim"`, `output = "none"`).
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct NoKeys {}

/// Reads the table `name` into `T`, an enum tagged by its key `tag` (`default` when the
/// table has none): the tag selects the variant, and the variant's struct the keys that
/// exist. Errors name the key: `frames.device is not a key of frames.backend = "pipe"
/// (its keys: path, format, width, height, timeout_ms)`.
pub(crate) fn tagged<T: DeserializeOwned>(
    check: &Checker,
    name: &str,
    tag: &str,
    default: Option<&str>,
    mut table: toml::Table,
) -> Result<T, ConfigError> {
    if let (false, Some(default)) = (table.contains_key(tag), default) {
        table.insert(tag.into(), default.into());
    }
    let read = |table: toml::Table| -> Result<T, String> {
        toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| e.message().to_string())
    };
    let message = match read(table.clone()) {
        Ok(raw) => return Ok(raw),
        Err(message) => message,
    };
    // serde's words, with the key they are about.
    let chosen = table
        .get(tag)
        .map(|v| format!("{name}.{tag} = {v}"))
        .unwrap_or_default();
    let listed = |text: &str| {
        let list = text
            .trim_start_matches(", expected ")
            .trim_start_matches("one of ");
        list.replace('`', "")
    };
    let explained = if let Some((key, rest)) = message
        .strip_prefix("unknown field `")
        .and_then(|m| m.split_once('`'))
    {
        if rest.starts_with(", there are no fields") {
            format!("{name}.{key} is not a key of {chosen}, which has none")
        } else {
            format!(
                "{name}.{key} is not a key of {chosen} (its keys: {})",
                listed(rest)
            )
        }
    } else if let Some((_, rest)) = message
        .strip_prefix("unknown variant `")
        .and_then(|m| m.split_once('`'))
    {
        format!("{chosen} is not one of: {}", listed(rest))
    } else if message == format!("missing field `{tag}`") {
        // The values there are: what an empty one is told.
        table.insert(tag.into(), "".into());
        let choices = read(table)
            .err()
            .and_then(|m| m.split_once('`').map(|(_, r)| r.to_string()))
            .and_then(|r| r.split_once('`').map(|(_, r)| listed(r)))
            .unwrap_or_default();
        format!("missing {name}.{tag} (one of: {choices})")
    } else {
        format!("[{name}]: {message}")
    };
    Err(check.inconsistent(explained))
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
