//! `[frames]`, `[daq]`, `[haptic]`: which backend drives each device kind. The default
//! for every kind is `"sim"`, the simulated lab, so a configuration that names no
//! hardware never touches any.
use serde::Deserialize;

use crate::config::{Checker, ConfigError};

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDevice {
    backend: Option<String>,
}

/// Where frames come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FramesBackend {
    Sim,
}

/// What drives the S100's rate inputs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DaqBackend {
    Sim,
}

/// The operator's device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HapticBackend {
    Sim,
}

/// Validated device selection.
#[derive(Debug, Clone, PartialEq, Eq)]
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
        let backend = |section: &str, raw: &RawDevice, known: &[&str]| -> Result<(), ConfigError> {
            match raw.backend.as_deref() {
                None => Ok(()),
                Some(name) if known.contains(&name) => Ok(()),
                Some(name) => Err(check.invalid(
                    &format!("{section}.backend"),
                    format_args!("{name:?}"),
                    &format!("must be one of {known:?}"),
                )),
            }
        };
        backend("frames", &frames, &["sim"])?;
        backend("daq", &daq, &["sim"])?;
        backend("haptic", &haptic, &["sim"])?;
        Ok(DevicesConfig::default())
    }
}
