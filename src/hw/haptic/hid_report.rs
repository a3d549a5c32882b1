//! HID reports as the `"hid"` haptic backend reads and writes them, in plain Rust (no
//! device needed, so always compiled and unit-tested): stylus axes are little-endian
//! bit fields of the input report (HID's own bit order), mapped to millimetres; the
//! button that switches probes is one bit of it; the force goes out as three
//! little-endian i16 in an output report; velocity is estimated from successive
//! positions.
use nalgebra::Vector3;

use super::config::{HidAxis, HidForce};
use super::SWITCH_BUTTON;

/// The field of `bits` bits starting `bit` bits into `report`, or None if it overruns.
pub fn field(report: &[u8], bit: usize, bits: u32, signed: bool) -> Option<i64> {
    let first = bit / 8;
    let last = (bit + bits as usize - 1) / 8;
    let bytes = report.get(first..=last)?;
    let word = bytes
        .iter()
        .rev()
        .fold(0u64, |acc, &b| acc << 8 | u64::from(b));
    let raw = (word >> (bit % 8)) & ((1u64 << bits) - 1);
    if signed && raw >> (bits - 1) & 1 == 1 {
        Some(raw as i64 - (1i64 << bits))
    } else {
        Some(raw as i64)
    }
}

/// One axis in millimetres: the raw range, clamped, spans `travel_mm` about its middle.
pub fn axis_mm(report: &[u8], axis: &HidAxis) -> Option<f64> {
    let raw = field(report, axis.bit, axis.bits, axis.signed)?.clamp(axis.min, axis.max);
    let span = (axis.max - axis.min) as f64;
    let centred = (raw - axis.min) as f64 / span - 0.5;
    let mm = centred * axis.travel_mm;
    Some(if axis.invert { -mm } else { mm })
}

/// The stylus position of a report.
pub fn position_mm(report: &[u8], axes: &[HidAxis; 3]) -> Option<Vector3<f64>> {
    Some(Vector3::new(
        axis_mm(report, &axes[0])?,
        axis_mm(report, &axes[1])?,
        axis_mm(report, &axes[2])?,
    ))
}

/// The buttons of a report, as [`HapticSample::buttons`](super::HapticSample::buttons):
/// [`SWITCH_BUTTON`] while the bit `switch_button_bit` is 1, else 0 (always 0 without
/// one). None if the report is too short to hold that bit.
pub fn buttons(report: &[u8], switch_button_bit: Option<usize>) -> Option<u32> {
    let Some(bit) = switch_button_bit else {
        return Some(0);
    };
    let held = field(report, bit, 1, false)? == 1;
    Some(if held { SWITCH_BUTTON } else { 0 })
}

/// Writes the output report for `force_n` into `out` (`report_length` bytes).
pub fn force_report_into(force_n: Vector3<f64>, config: &HidForce, out: &mut [u8]) {
    out.fill(0);
    out[0] = config.report_id;
    for (&at, f) in config.bytes.iter().zip(force_n.iter()) {
        let scaled = (f / config.full_scale_n * 32767.0).round();
        let value = if scaled.is_finite() {
            scaled.clamp(-32767.0, 32767.0) as i16
        } else {
            0
        };
        out[at..at + 2].copy_from_slice(&value.to_le_bytes());
    }
}

/// Velocity from successive positions, low-pass filtered (time constant `tau_s`).
#[derive(Debug, Clone)]
pub struct VelocityEstimator {
    last: Option<(Vector3<f64>, f64)>,
    velocity_mm_s: Vector3<f64>,
    tau_s: f64,
}

impl VelocityEstimator {
    pub fn new(tau_s: f64) -> Self {
        VelocityEstimator {
            last: None,
            velocity_mm_s: Vector3::zeros(),
            tau_s,
        }
    }

    /// A new position at `t_s`; returns the filtered velocity.
    pub fn update(&mut self, position_mm: Vector3<f64>, t_s: f64) -> Vector3<f64> {
        if let Some((last, last_s)) = self.last {
            let dt = t_s - last_s;
            if dt > 0.0 {
                let raw = (position_mm - last) / dt;
                let alpha = dt / (self.tau_s + dt);
                self.velocity_mm_s += (raw - self.velocity_mm_s) * alpha;
            }
        }
        self.last = Some((position_mm, t_s));
        self.velocity_mm_s
    }

    /// The stylus is known to be still at `position_mm` (a silent device).
    pub fn hold(&mut self, position_mm: Vector3<f64>, t_s: f64) -> Vector3<f64> {
        self.last = Some((position_mm, t_s));
        self.velocity_mm_s = Vector3::zeros();
        self.velocity_mm_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Logitech Extreme 3D Pro's 7-byte input report layout: X and Y 10 bits, hat
    /// 4, twist 8, then buttons and throttle. Axes as a lab would configure it: x = X,
    /// y = -Y (forward is up), z = twist.
    fn extreme_3d_axes() -> [HidAxis; 3] {
        let axis = |bit, bits, max, invert| HidAxis {
            bit,
            bits,
            signed: false,
            min: 0,
            max,
            travel_mm: 60.0,
            invert,
        };
        [
            axis(0, 10, 1023, false),
            axis(10, 10, 1023, true),
            axis(24, 8, 255, false),
        ]
    }

    #[test]
    fn bit_fields_little_endian_and_signed() {
        let report = [0xff, 0x03, 0x80, 0xff, 0x00, 0x00, 0x00];
        assert_eq!(field(&report, 0, 10, false), Some(1023));
        assert_eq!(field(&report, 10, 10, false), Some(0));
        assert_eq!(field(&report, 20, 4, false), Some(8));
        assert_eq!(field(&report, 24, 8, false), Some(255));
        assert_eq!(field(&report, 24, 8, true), Some(-1));
        assert_eq!(field(&[0x00, 0x80], 0, 16, true), Some(-32768));
        assert_eq!(field(&report, 50, 8, false), None, "past the end");
    }

    #[test]
    fn extreme_3d_reports_to_millimetres() {
        let axes = extreme_3d_axes();
        // Centred (X = Y = 512, hat released = 8, twist 128).
        let centre = [0x00, 0x02, 0x88, 0x80, 0x00, 0x00, 0x00];
        let p = position_mm(&centre, &axes).unwrap();
        assert!(
            (p - Vector3::new(30.0 / 1023.0, -30.0 / 1023.0, 30.0 / 255.0)).norm() < 1e-12,
            "{p}"
        );
        // Full right, full forward (Y = 0), twisted right (255).
        let corner = [0xff, 0x03, 0x80, 0xff, 0x04, 0x00, 0x00];
        assert_eq!(
            position_mm(&corner, &axes),
            Some(Vector3::new(30.0, 30.0, 30.0))
        );
        assert_eq!(
            position_mm(&corner[..3], &axes),
            None,
            "a short report is not used"
        );
    }

    #[test]
    fn switch_button_from_its_bit() {
        // The Extreme 3D Pro's buttons 1 to 8 are byte 4: the thumb button (2) is bit 33.
        let thumb = [0x00, 0x02, 0x88, 0x80, 0x02, 0x00, 0x00];
        let others = [0xff, 0xff, 0xff, 0xff, 0xfd, 0xff, 0xff];
        assert_eq!(buttons(&thumb, Some(33)), Some(SWITCH_BUTTON));
        assert_eq!(buttons(&others, Some(33)), Some(0), "every other bit set");
        assert_eq!(buttons(&thumb, Some(32)), Some(0), "the trigger is not it");
        assert_eq!(
            buttons(&thumb, None),
            Some(0),
            "no switch button configured"
        );
        assert_eq!(
            buttons(&[0xff; 7], Some(55)),
            Some(SWITCH_BUTTON),
            "last bit"
        );
        assert_eq!(buttons(&thumb[..4], Some(33)), None, "a short report");
        assert_eq!(buttons(&thumb[..4], None), Some(0));
    }

    #[test]
    fn force_report_scales_and_clamps() {
        let config = HidForce {
            report_id: 2,
            report_length: 8,
            bytes: [1, 3, 5],
            full_scale_n: 4.0,
        };
        let mut out = [0xaa; 8];
        force_report_into(Vector3::new(2.0, -4.0, 9.0), &config, &mut out);
        assert_eq!(out, [2, 0x00, 0x40, 0x01, 0x80, 0xff, 0x7f, 0x00]);
        force_report_into(Vector3::new(f64::NAN, 0.0, 0.0), &config, &mut out);
        assert_eq!(out, [2, 0, 0, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn velocity_follows_a_ramp() {
        let mut v = VelocityEstimator::new(0.005);
        let mut last = Vector3::zeros();
        for i in 0..200 {
            let t = i as f64 * 0.001;
            last = v.update(Vector3::new(10.0 * t, 0.0, -3.0 * t), t);
        }
        assert!(
            (last - Vector3::new(10.0, 0.0, -3.0)).norm() < 1e-6,
            "{last}"
        );
    }
}
