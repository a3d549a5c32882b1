//! The `"hid"` haptic backend: a USB-HID device through hidapi, its report layout from
//! `[haptic.x/y/z]`, the button that switches probes from `switch_button_bit` and, for a
//! HID haptic device, `[haptic.force]`. A plain joystick has no force output: it gives
//! position only, and the log says so, since the operator then feels nothing of the tip
//! force.
//!
//! Each 1 kHz `read` drains the reports waiting (non-blocking `hid_read_timeout(0)`,
//! into a reused buffer) and keeps the newest; `write_force` sends an output report
//! only when it changes. Nothing allocates after opening. A read error (unplugged) is
//! [`HapticError::Lost`].
use nalgebra::Vector3;

use super::config::HidConfig;
use super::hid_report::{buttons, force_report_into, position_mm, VelocityEstimator};
use super::hidapi_sys::{Device, HidError};
use super::{HapticDevice, HapticError, HapticSample};

/// Reports drained per call at most (a device sends one per ms at the fastest).
const MAX_REPORTS_PER_READ: usize = 64;
/// No report for this long: the stylus is taken to be still.
const SILENT_IS_STILL_S: f64 = 0.02;
/// How long opening waits for a first report to know where the stylus is.
const FIRST_REPORT_MS: i32 = 200;

pub struct HidHaptic {
    name: String,
    config: HidConfig,
    device: Device,
    report: Vec<u8>,
    position_mm: Vector3<f64>,
    /// The newest report's buttons (a device that reports only on change holds them).
    buttons: u32,
    velocity: VelocityEstimator,
    velocity_mm_s: Vector3<f64>,
    fresh: bool,
    last_report_s: f64,
    out: Vec<u8>,
    sent: Vec<u8>,
    forces_enabled: bool,
}

impl HidHaptic {
    pub fn open(config: &HidConfig) -> Result<HidHaptic, HapticError> {
        let name = format!("hid:{:04x}:{:04x}", config.vendor_id, config.product_id);
        let device =
            Device::open(config.vendor_id, config.product_id).map_err(|e| HapticError::Open {
                device: name.clone(),
                reason: e.to_string(),
            })?;
        let out_len = config.force.map_or(0, |f| f.report_length);
        let mut hid = HidHaptic {
            name,
            config: config.clone(),
            device,
            report: vec![0; config.report_length.max(64)],
            position_mm: Vector3::zeros(),
            buttons: 0,
            velocity: VelocityEstimator::new(0.01),
            velocity_mm_s: Vector3::zeros(),
            fresh: false,
            last_report_s: f64::NEG_INFINITY,
            out: vec![0; out_len],
            sent: vec![0; out_len],
            forces_enabled: false,
        };
        let n = hid
            .device
            .read_timeout(&mut hid.report, FIRST_REPORT_MS)
            .map_err(|e| hid.lost(e))?;
        if !hid.take(n) {
            tracing::warn!("{}: no input report within {FIRST_REPORT_MS} ms; assuming the stylus is centred until one arrives", hid.name);
        }
        if config.force.is_none() {
            tracing::warn!(
                "{}: no [haptic.force] report: a joystick, position only, NO FORCE FEEDBACK (the operator will not feel the tip force)",
                hid.name
            );
        }
        hid.send_zero();
        Ok(hid)
    }

    fn lost(&self, e: HidError) -> HapticError {
        HapticError::Lost {
            device: self.name.clone(),
            reason: e.to_string(),
        }
    }

    /// Uses the report of length `n` in the buffer if it is ours; true if it was.
    fn take(&mut self, n: usize) -> bool {
        let report = &self.report[..n];
        if n == 0 || self.config.report_id.is_some_and(|id| report[0] != id) {
            return false;
        }
        let position = position_mm(report, &self.config.axes);
        match (position, buttons(report, self.config.switch_button_bit)) {
            (Some(p), Some(b)) => {
                self.position_mm = p;
                self.buttons = b;
                self.fresh = true;
                true
            }
            _ => false,
        }
    }

    fn send(&mut self) -> Result<(), HidError> {
        if self.out.is_empty() || self.out == self.sent {
            return Ok(());
        }
        self.device.write(&self.out)?;
        self.sent.copy_from_slice(&self.out);
        Ok(())
    }

    fn send_zero(&mut self) {
        if let Some(force) = self.config.force {
            force_report_into(Vector3::zeros(), &force, &mut self.out);
            self.sent.fill(0xff); // force the write
            if let Err(e) = self.send() {
                tracing::error!("{}: zero force report: {e}", self.name);
            }
        }
    }
}

impl HapticDevice for HidHaptic {
    fn name(&self) -> &str {
        &self.name
    }

    fn has_force_feedback(&self) -> bool {
        self.config.force.is_some()
    }

    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError> {
        for _ in 0..MAX_REPORTS_PER_READ {
            let n = self
                .device
                .read_timeout(&mut self.report, 0)
                .map_err(|e| self.lost(e))?;
            if n == 0 {
                break;
            }
            self.take(n);
        }
        // A device that reports only on change is still when it is silent.
        if self.fresh {
            self.last_report_s = now_s;
        }
        if std::mem::take(&mut self.fresh) {
            self.velocity_mm_s = self.velocity.update(self.position_mm, now_s);
        } else if now_s - self.last_report_s > SILENT_IS_STILL_S {
            self.velocity_mm_s = self.velocity.hold(self.position_mm, now_s);
        }
        Ok(HapticSample {
            position_mm: self.position_mm,
            velocity_mm_s: self.velocity_mm_s,
            buttons: self.buttons,
        })
    }

    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError> {
        let Some(force) = self.config.force.filter(|_| self.forces_enabled) else {
            return Ok(());
        };
        force_report_into(force_n, &force, &mut self.out);
        self.send().map_err(|e| self.lost(e))
    }

    fn set_forces_enabled(&mut self, enabled: bool) -> Result<(), HapticError> {
        self.forces_enabled = enabled;
        if let (false, Some(force)) = (enabled, self.config.force) {
            force_report_into(Vector3::zeros(), &force, &mut self.out);
            self.send().map_err(|e| self.lost(e))?;
        }
        Ok(())
    }
}

impl Drop for HidHaptic {
    fn drop(&mut self) {
        self.send_zero();
    }
}
