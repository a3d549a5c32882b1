//! Opening the real backend a configuration names, for each device kind. A `"sim"`
//! backend gives `None` (the lab builds its simulated twin, which needs the rest of the
//! simulated lab). A backend whose cargo feature is not compiled in is an error that
//! says which build it needs, never a panic; [`check_compiled`] finds that before any
//! device is touched.
use super::config::{DaqBackend, DevicesConfig, FramesBackend, HapticBackend, Positioner};
use super::daq::{DaqError, RateOutput};
use super::frames::{pipe::PipeSource, FrameError, FrameSource};
use super::haptic::{HapticDevice, HapticError};
use super::Clock;

/// Why a device could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error("{section}.backend = {backend:?} needs a build with --features {feature} (this build has: {compiled})")]
    NotCompiled {
        section: String,
        backend: &'static str,
        feature: &'static str,
        compiled: String,
    },
    #[error(transparent)]
    Frames(#[from] FrameError),
    #[error(transparent)]
    Daq(#[from] DaqError),
    #[error(transparent)]
    Haptic(#[from] HapticError),
}

/// The hardware features this build has.
pub fn compiled_features() -> Vec<&'static str> {
    let all = [
        ("v4l2", cfg!(feature = "v4l2")),
        ("comedi", cfg!(feature = "comedi")),
        ("openhaptics", cfg!(feature = "openhaptics")),
        ("hidapi", cfg!(feature = "hidapi")),
    ];
    all.iter()
        .filter(|(_, on)| *on)
        .map(|(name, _)| *name)
        .collect()
}

fn not_compiled(section: &str, backend: &'static str, feature: &'static str) -> OpenError {
    let compiled = compiled_features();
    OpenError::NotCompiled {
        section: section.to_string(),
        backend,
        feature,
        compiled: if compiled.is_empty() {
            "no hardware features".into()
        } else {
            compiled.join(", ")
        },
    }
}

/// Every configured backend is compiled in (checked before opening anything).
pub fn check_compiled(devices: &DevicesConfig) -> Result<(), OpenError> {
    let frames = match devices.frames {
        FramesBackend::V4l2(_) if !cfg!(feature = "v4l2") => Some(("frames", "v4l2", "v4l2")),
        _ => None,
    };
    let daq = devices.positioners.iter().find_map(|p| match p.daq {
        DaqBackend::Comedi(_) if !cfg!(feature = "comedi") => {
            Some((p.section.as_str(), "comedi", "comedi"))
        }
        _ => None,
    });
    let haptic = match devices.haptic {
        HapticBackend::OpenHaptics(_) if !cfg!(feature = "openhaptics") => {
            Some(("haptic", "openhaptics", "openhaptics"))
        }
        HapticBackend::Hid(_) if !cfg!(feature = "hidapi") => Some(("haptic", "hid", "hidapi")),
        _ => None,
    };
    match frames.or(daq).or(haptic) {
        Some((section, backend, feature)) => Err(not_compiled(section, backend, feature)),
        None => Ok(()),
    }
}

/// The configured frame source, or None for `"sim"`.
pub fn frames(
    backend: &FramesBackend,
    clock: Clock,
) -> Result<Option<Box<dyn FrameSource>>, OpenError> {
    match backend {
        FramesBackend::Sim => Ok(None),
        FramesBackend::Pipe(c) => Ok(Some(Box::new(PipeSource::open(c, clock)?))),
        #[cfg(feature = "v4l2")]
        FramesBackend::V4l2(c) => Ok(Some(Box::new(super::frames::v4l2::V4l2Source::open(
            c, clock,
        )?))),
        #[cfg(not(feature = "v4l2"))]
        FramesBackend::V4l2(_) => Err(not_compiled("frames", "v4l2", "v4l2")),
    }
}

/// The configured rate output of a positioner, or None for `"sim"`.
pub fn daq(positioner: &Positioner) -> Result<Option<Box<dyn RateOutput>>, OpenError> {
    match &positioner.daq {
        DaqBackend::Sim => Ok(None),
        #[cfg(feature = "comedi")]
        DaqBackend::Comedi(c) => Ok(Some(Box::new(super::daq::comedi::ComediRate::open(c)?))),
        #[cfg(not(feature = "comedi"))]
        DaqBackend::Comedi(_) => Err(not_compiled(&positioner.section, "comedi", "comedi")),
    }
}

/// The configured haptic device, or None for `"sim"`.
pub fn haptic(backend: &HapticBackend) -> Result<Option<Box<dyn HapticDevice>>, OpenError> {
    match backend {
        HapticBackend::Sim => Ok(None),
        #[cfg(feature = "openhaptics")]
        HapticBackend::OpenHaptics(c) => Ok(Some(Box::new(
            super::haptic::openhaptics::OpenHaptics::open(c)?,
        ))),
        #[cfg(not(feature = "openhaptics"))]
        HapticBackend::OpenHaptics(_) => Err(not_compiled("haptic", "openhaptics", "openhaptics")),
        #[cfg(feature = "hidapi")]
        HapticBackend::Hid(c) => Ok(Some(Box::new(super::haptic::hid::HidHaptic::open(c)?))),
        #[cfg(not(feature = "hidapi"))]
        HapticBackend::Hid(_) => Err(not_compiled("haptic", "hid", "hidapi")),
    }
}
