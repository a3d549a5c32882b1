//! `[haptic]`: the operator's device. `"sim"` (the scripted virtual operator),
//! `"openhaptics"` (a PHANToM through OpenHaptics' HD API, `libHD.so` loaded at run
//! time) or `"hid"` (a USB-HID device through hidapi: a HID haptic device, or a plain
//! joystick that gives position without force feedback). For `"hid"` the report layout
//! comes from `[haptic.x]`, `[haptic.y]`, `[haptic.z]`, `switch_button_bit` for the
//! button that switches probes and, for force output, `[haptic.force]`.
use serde::Deserialize;

use crate::checks::{Checker, ConfigError, List, Range};

/// The stylus travel a HID axis's raw span maps to: a PHANToM's workspace is 70 to
/// 380 mm across.
const TRAVEL_MM: Range = Range::new(1.0, 1000.0, "mm");
/// A haptic device's force: the PHANToM Touch peaks at 3.3 N, the Premium 1.5 at 8.5 N.
const FULL_SCALE_N: Range = Range::new(0.01, 10.0, "N");
use crate::checks::{in_range, required, NoKeys};

/// The operator's device.
#[derive(Debug, Clone, PartialEq)]
pub enum HapticBackend {
    Sim,
    OpenHaptics(OpenHapticsConfig),
    Hid(HidConfig),
}

/// `[haptic]` as written: `backend` selects the keys that exist.
#[derive(Debug, Deserialize)]
#[serde(tag = "backend", rename_all = "lowercase")]
pub(crate) enum RawHaptic {
    Sim(NoKeys),
    OpenHaptics(RawOpenHaptics),
    /// Boxed: its layout outweighs the other backends' keys many times over.
    Hid(Box<RawHid>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawOpenHaptics {
    library: Option<String>,
    device_name: Option<String>,
    stall_ms: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawHid {
    vendor_id: Option<i64>,
    product_id: Option<i64>,
    report_id: Option<i64>,
    report_length: Option<i64>,
    switch_button_bit: Option<i64>,
    x: Option<RawHidAxis>,
    y: Option<RawHidAxis>,
    z: Option<RawHidAxis>,
    force: Option<RawHidForce>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHidAxis {
    bit: i64,
    bits: i64,
    signed: Option<bool>,
    min: i64,
    max: i64,
    travel_mm: f64,
    invert: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHidForce {
    report_id: i64,
    report_length: i64,
    bytes: List<i64, 3>,
    full_scale_n: f64,
}

/// Validated `[haptic]` of `backend = "openhaptics"`.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenHapticsConfig {
    /// Passed to dlopen: a file name searched the usual way, or a path.
    pub library: String,
    /// The device name given to `hdInitDevice` (None: `HD_DEFAULT_DEVICE`).
    pub device_name: Option<String>,
    /// The servo loop not ticking for this long means the device is lost.
    pub stall_ms: u64,
}

/// One stylus axis in the input report: a little-endian bit field (HID's bit order),
/// whose raw `min..=max` maps to `travel_mm` centred on the middle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HidAxis {
    /// Offset of the field's lowest bit from the start of the report (byte 0 is the
    /// report id when the device numbers its reports).
    pub bit: usize,
    /// Width of the field, 1..=32 bits.
    pub bits: u32,
    /// Two's complement field.
    pub signed: bool,
    pub min: i64,
    pub max: i64,
    pub travel_mm: f64,
    pub invert: bool,
}

/// The output report that renders a force: three little-endian i16, +-32767 = full scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HidForce {
    pub report_id: u8,
    pub report_length: usize,
    pub bytes: [usize; 3],
    pub full_scale_n: f64,
}

/// Validated `[haptic]` of `backend = "hid"`.
#[derive(Debug, Clone, PartialEq)]
pub struct HidConfig {
    pub vendor_id: u16,
    pub product_id: u16,
    /// Only input reports whose first byte is this are used.
    pub report_id: Option<u8>,
    pub report_length: usize,
    pub axes: [HidAxis; 3],
    /// The input report bit (offset from the start of the report, as
    /// [`HidAxis::bit`]) of the button that switches probes: reported as
    /// [`SWITCH_BUTTON`](super::SWITCH_BUTTON) while it is 1. None: no such button.
    pub switch_button_bit: Option<usize>,
    /// None: a joystick, position only.
    pub force: Option<HidForce>,
}

impl RawHaptic {
    pub(crate) fn validate(self, check: &Checker) -> Result<HapticBackend, ConfigError> {
        Ok(match self {
            RawHaptic::Sim(NoKeys {}) => HapticBackend::Sim,
            RawHaptic::OpenHaptics(raw) => HapticBackend::OpenHaptics(raw.validate(check)?),
            RawHaptic::Hid(raw) => HapticBackend::Hid(raw.validate(check)?),
        })
    }
}

impl RawOpenHaptics {
    fn validate(self, check: &Checker) -> Result<OpenHapticsConfig, ConfigError> {
        let stall_ms = self.stall_ms.map_or(Ok(50), |s| {
            in_range(check, "haptic.stall_ms", s, (5, 10_000), "ms").map(u64::from)
        })?;
        Ok(OpenHapticsConfig {
            library: self.library.unwrap_or_else(|| "libHD.so".into()),
            device_name: self.device_name,
            stall_ms,
        })
    }
}

impl RawHid {
    fn validate(self, check: &Checker) -> Result<HidConfig, ConfigError> {
        let id = |key: &str, v: Option<i64>| -> Result<u16, ConfigError> {
            let v = required(check, key, "hid", v)?;
            in_range(check, key, v, (0, 0xffff), "").map(|v| v as u16)
        };
        let vendor_id = id("haptic.vendor_id", self.vendor_id)?;
        let product_id = id("haptic.product_id", self.product_id)?;
        let report_id = self
            .report_id
            .map(|r| in_range(check, "haptic.report_id", r, (0, 255), "").map(|r| r as u8))
            .transpose()?;
        let report_length = required(check, "haptic.report_length", "hid", self.report_length)?;
        let report_length = in_range(
            check,
            "haptic.report_length",
            report_length,
            (1, 1024),
            "bytes",
        )?;
        let switch_button_bit = self
            .switch_button_bit
            .map(|b| {
                let last = 8 * i64::from(report_length) - 1;
                in_range(check, "haptic.switch_button_bit", b, (0, last), "").map(|b| b as usize)
            })
            .transpose()?;
        let mut axes = Vec::with_capacity(3);
        for (name, raw) in [("x", self.x), ("y", self.y), ("z", self.z)] {
            let key = format!("haptic.{name}");
            let raw = required(check, &format!("[{key}]"), "hid", raw)?;
            axes.push(raw.validate(check, &key, report_length as usize)?);
        }
        let force = self.force.map(|f| f.validate(check)).transpose()?;
        Ok(HidConfig {
            vendor_id,
            product_id,
            report_id,
            report_length: report_length as usize,
            axes: [axes[0], axes[1], axes[2]],
            switch_button_bit,
            force,
        })
    }
}

impl RawHidAxis {
    fn validate(self, check: &Checker, key: &str, length: usize) -> Result<HidAxis, ConfigError> {
        let bits = in_range(check, &format!("{key}.bits"), self.bits, (1, 32), "")?;
        let last = 8 * length as i64 - i64::from(bits);
        let bit = in_range(check, &format!("{key}.bit"), self.bit, (0, last), "")? as usize;
        if self.max <= self.min {
            return Err(check.invalid(
                &format!("{key}.max"),
                self.max,
                &format!("must be > {key}.min ({})", self.min),
            ));
        }
        Ok(HidAxis {
            bit,
            bits,
            signed: self.signed.unwrap_or(false),
            min: self.min,
            max: self.max,
            travel_mm: check.number(&format!("{key}.travel_mm"), self.travel_mm, TRAVEL_MM)?,
            invert: self.invert.unwrap_or(false),
        })
    }
}

impl RawHidForce {
    fn validate(self, check: &Checker) -> Result<HidForce, ConfigError> {
        let report_id = in_range(
            check,
            "haptic.force.report_id",
            self.report_id,
            (0, 255),
            "",
        )?;
        let length = in_range(
            check,
            "haptic.force.report_length",
            self.report_length,
            (7, 1024),
            "bytes",
        )?;
        let mut bytes = [0usize; 3];
        for (slot, b) in bytes.iter_mut().zip(self.bytes.0) {
            *slot = in_range(
                check,
                "haptic.force.bytes",
                b,
                (1, i64::from(length) - 2),
                "",
            )? as usize;
        }
        Ok(HidForce {
            report_id: report_id as u8,
            report_length: length as usize,
            bytes,
            full_scale_n: check.number(
                "haptic.force.full_scale_n",
                self.full_scale_n,
                FULL_SCALE_N,
            )?,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::config::testing::{error_of, parse};
    use crate::hw::haptic::config::*;

    const JOYSTICK: &str = "[haptic]\nbackend = \"hid\"\nvendor_id = 0x046d\nproduct_id = 0xc215\n\
        report_length = 7\n\
        [haptic.x]\nbit = 0\nbits = 10\nmin = 0\nmax = 1023\ntravel_mm = 60\n\
        [haptic.y]\nbit = 10\nbits = 10\nmin = 0\nmax = 1023\ntravel_mm = 60\ninvert = true\n\
        [haptic.z]\nbit = 40\nbits = 8\nmin = 0\nmax = 255\ntravel_mm = 60\n";

    #[test]
    fn openhaptics_defaults() {
        let cfg = parse("[haptic]\nbackend = \"openhaptics\"\n").unwrap();
        assert_eq!(
            cfg.devices.haptic,
            HapticBackend::OpenHaptics(OpenHapticsConfig {
                library: "libHD.so".into(),
                device_name: None,
                stall_ms: 50
            })
        );
    }

    #[test]
    fn hid_joystick_layout() {
        let HapticBackend::Hid(h) = parse(JOYSTICK).unwrap().devices.haptic else {
            panic!("not hid")
        };
        assert_eq!(
            (h.vendor_id, h.product_id, h.report_length),
            (0x046d, 0xc215, 7)
        );
        assert_eq!(
            (h.axes[1].bit, h.axes[1].bits, h.axes[1].signed),
            (10, 10, false)
        );
        assert!(h.axes[1].invert && h.force.is_none());
        assert_eq!(h.switch_button_bit, None, "no switch button unless named");
    }

    #[test]
    fn hid_switch_button_bit() {
        let with = |bit: &str| {
            JOYSTICK.replace(
                "report_length = 7\n",
                &format!("report_length = 7\nswitch_button_bit = {bit}\n"),
            )
        };
        let HapticBackend::Hid(h) = parse(&with("33")).unwrap().devices.haptic else {
            panic!("not hid")
        };
        assert_eq!(h.switch_button_bit, Some(33));
        let HapticBackend::Hid(h) = parse(&with("55")).unwrap().devices.haptic else {
            panic!("not hid")
        };
        assert_eq!(h.switch_button_bit, Some(55), "the report's last bit");
        assert_eq!(
            error_of(&with("56")),
            "lab.toml: haptic.switch_button_bit = 56 is out of range: accepted 0 to 55"
        );
        assert_eq!(
            error_of(&with("-1")),
            "lab.toml: haptic.switch_button_bit = -1 is out of range: accepted 0 to 55"
        );
        let msg = error_of(&JOYSTICK.replace("report_length = 7", "switch_button = 33"));
        assert_eq!(
            msg,
            "lab.toml: haptic.switch_button is not a key of haptic.backend = \"hid\" \
             (its keys: vendor_id, product_id, report_id, report_length, switch_button_bit, \
             x, y, z, force)"
        );
    }

    #[test]
    fn hid_errors_name_key_and_value() {
        let msg = error_of(&JOYSTICK.replace("bit = 40", "bit = 50"));
        assert_eq!(
            msg,
            "lab.toml: haptic.z.bit = 50 is out of range: accepted 0 to 48"
        );
        let msg = error_of(&JOYSTICK.replace("bits = 8", "bits = 33"));
        assert_eq!(
            msg,
            "lab.toml: haptic.z.bits = 33 is out of range: accepted 1 to 32"
        );
        let msg = error_of(&JOYSTICK.replace("product_id = 0xc215", "product_id = 70000"));
        assert_eq!(
            msg,
            "lab.toml: haptic.product_id = 70000 is out of range: accepted 0 to 65535"
        );
        let msg = error_of("[haptic]\nbackend = \"openhaptics\"\nvendor_id = 1\n");
        assert_eq!(
            msg,
            "lab.toml: haptic.vendor_id is not a key of haptic.backend = \"openhaptics\" \
             (its keys: library, device_name, stall_ms)"
        );
    }
}
