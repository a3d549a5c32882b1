//! The `"comedi"` DAQ backend: the S100 controller's rate inputs driven by a comedi
//! board, each stage axis in its configured style (see [`super::config`]):
//!
//! - analog: `zero_v + volts_per_um_s * v` through the channel's range table
//!   (`comedi_get_range` / `comedi_find_range`, `comedi_from_phys`), clamped to the range;
//! - step/direction: an NI general-purpose counter toggles its output on terminal count,
//!   reloading alternately from load A (low time) and load B (high time) on the 20 MHz
//!   timebase, so the pulse rate is `|v| * pulses_per_um`; a DIO line gives the sign.
//!
//! An axis may name its own board (`daq.<axis>.device`): a PCI-6034E has two counters,
//! so a third step/direction axis needs a second board.
//!
//! `write_velocity` runs 1000 times a second: it allocates nothing and only talks to the
//! board when an axis's raw output changes. `zero` (and `Drop`) always write: analog
//! outputs at their zero voltage, counters disarmed, direction lines low.
use nalgebra::Vector3;

use super::comedi_sys::{self as sys, gpct, ComediError, Device, Range};
use super::config::{AnalogAxis, AxisOutput, ComediConfig, RangeChoice, StepDirAxis};
use super::{DaqError, RateOutput};

/// Slowest pulse train: the 24-bit counter's longest period on the 20 MHz timebase.
const MAX_PERIOD_TICKS: u32 = (1 << 24) - 1;
const MIN_PERIOD_TICKS: u32 = 4;
const TIMEBASE_HZ: f64 = 1e9 / gpct::TIMEBASE_1_PERIOD_NS as f64;

struct Analog {
    subdevice: u32,
    channel: u32,
    range_index: u32,
    range: Range,
    maxdata: u32,
    volts_per_um_s: f64,
    zero_v: f64,
    last: Option<u32>,
}

struct Pulse {
    config: StepDirAxis,
    /// (low ticks, high ticks) of the running train; None: disarmed.
    running: Option<(u32, u32)>,
    direction_high: Option<bool>,
}

enum Axis {
    None,
    /// (board index, output)
    Analog(usize, Analog),
    Pulse(usize, Pulse),
}

pub struct ComediRate {
    name: String,
    /// One per distinct device path, in the order the axes name them.
    boards: Vec<Device>,
    axes: [Axis; 3],
}

fn open_error(device: &str, reason: impl std::fmt::Display) -> DaqError {
    DaqError::Open {
        device: device.into(),
        reason: reason.to_string(),
    }
}

fn write_error(e: ComediError) -> DaqError {
    DaqError::Write {
        device: e.device,
        reason: format!("{} failed: {}", e.call, e.message),
    }
}

impl ComediRate {
    /// Opens the board(s), checks every axis's subdevices and sets all outputs to zero.
    pub fn open(config: &ComediConfig) -> Result<ComediRate, DaqError> {
        let mut boards: Vec<Device> = Vec::new();
        let mut names: Vec<String> = Vec::new();
        let mut axes = [Axis::None, Axis::None, Axis::None];
        let wiring = config.axes.iter().zip(&config.axis_devices);
        for ((slot, (axis, path)), label) in axes.iter_mut().zip(wiring).zip(["x", "y", "z"]) {
            if *axis == AxisOutput::None {
                continue;
            }
            let board = match boards
                .iter()
                .position(|b| b.path() == path.display().to_string())
            {
                Some(i) => i,
                None => {
                    let shown = path.display().to_string();
                    let device = Device::open(path).map_err(|e| open_error(&shown, e.message))?;
                    names.push(format!("{shown} ({})", device.board_name()));
                    boards.push(device);
                    boards.len() - 1
                }
            };
            let device = &boards[board];
            let what = |e: String| {
                open_error(
                    &format!("comedi:{}", names[board]),
                    format!("daq.{label}: {e}"),
                )
            };
            *slot = match axis {
                AxisOutput::None => Axis::None,
                AxisOutput::Analog(a) => Axis::Analog(
                    board,
                    open_analog(device, &device.board_name(), a).map_err(what)?,
                ),
                AxisOutput::StepDir(s) => Axis::Pulse(board, open_pulse(device, s).map_err(what)?),
            };
        }
        let name = format!("comedi:{}", names.join(" + "));
        let mut rate = ComediRate { name, boards, axes };
        rate.zero(0.0)?;
        Ok(rate)
    }
}

fn expect_type(device: &Device, subd: u32, wanted: &[i32], what: &str) -> Result<(), String> {
    let found = device.subdevice_type(subd).map_err(|e| e.to_string())?;
    if wanted.contains(&found) {
        Ok(())
    } else {
        Err(format!(
            "subdevice {subd} is not {what} (comedi subdevice type {found})"
        ))
    }
}

fn open_analog(device: &Device, board: &str, a: &AnalogAxis) -> Result<Analog, String> {
    expect_type(device, a.subdevice, &[sys::SUBD_AO], "an analog output").map_err(|e| {
        format!("{e}; a board without analog outputs (e.g. the PCI-6034E, {board} here) needs output = \"step_dir\"")
    })?;
    let channels = device.n_channels(a.subdevice).map_err(|e| e.to_string())?;
    if a.channel >= channels {
        return Err(format!(
            "channel {} does not exist (subdevice {} has {channels})",
            a.channel, a.subdevice
        ));
    }
    let range_index = match a.range {
        RangeChoice::Index(i) => i,
        RangeChoice::Volts { min_v, max_v } => device
            .find_range(a.subdevice, a.channel, min_v, max_v)
            .map_err(|e| format!("no range holds [{min_v}, {max_v}] V: {e}"))?,
    };
    let range = device
        .range(a.subdevice, a.channel, range_index)
        .map_err(|e| e.to_string())?;
    if range.unit != sys::UNIT_VOLT {
        return Err(format!("range {range_index} is not in volts"));
    }
    if !(range.min..=range.max).contains(&a.zero_v) {
        return Err(format!(
            "zero_v = {} V is outside range {range_index} [{}, {}] V",
            a.zero_v, range.min, range.max
        ));
    }
    Ok(Analog {
        subdevice: a.subdevice,
        channel: a.channel,
        range_index,
        range,
        maxdata: device
            .maxdata(a.subdevice, a.channel)
            .map_err(|e| e.to_string())?,
        volts_per_um_s: a.volts_per_um_s,
        zero_v: a.zero_v,
        last: None,
    })
}

fn open_pulse(device: &Device, s: &StepDirAxis) -> Result<Pulse, String> {
    let c = s.counter_subdevice;
    expect_type(device, c, &[sys::SUBD_COUNTER], "a counter")?;
    expect_type(
        device,
        s.dio_subdevice,
        &[sys::SUBD_DIO, sys::SUBD_DO],
        "a digital output",
    )?;
    let e = |e: ComediError| e.to_string();
    device.reset(c).map_err(e)?;
    device
        .set_gate_source(c, 0, 0, gpct::DISABLED_GATE_SELECT | sys::CR_EDGE)
        .map_err(e)?;
    // E-series counters have no second gate; that call failing is expected there.
    let _ = device.set_gate_source(c, 0, 1, gpct::DISABLED_GATE_SELECT | sys::CR_EDGE);
    device
        .set_counter_mode(c, 0, gpct::PULSE_TRAIN_MODE)
        .map_err(e)?;
    let (clock, period) = (gpct::TIMEBASE_1_CLOCK_SRC, gpct::TIMEBASE_1_PERIOD_NS);
    device.set_clock_source(c, 0, clock, period).map_err(e)?;
    device
        .dio_config_output(s.dio_subdevice, s.direction_channel)
        .map_err(e)?;
    Ok(Pulse {
        config: s.clone(),
        running: None,
        direction_high: None,
    })
}

/// The raw output for a voltage, clamped to the range.
fn analog_code(a: &Analog, volts: f64) -> u32 {
    let volts = if volts.is_finite() {
        volts.clamp(a.range.min, a.range.max)
    } else {
        a.zero_v
    };
    Device::from_phys(volts, &a.range, a.maxdata)
}

/// (low ticks, high ticks) of a pulse train at `rate_hz`, or None below the slowest.
pub fn pulse_ticks(rate_hz: f64) -> Option<(u32, u32)> {
    let period = (TIMEBASE_HZ / rate_hz).round();
    if !(period.is_finite() && period <= f64::from(MAX_PERIOD_TICKS)) {
        return None;
    }
    let period = (period as u32).max(MIN_PERIOD_TICKS);
    let high = period / 2;
    Some((period - high, high))
}

impl Analog {
    fn write(
        &mut self,
        device: &Device,
        velocity_um_s: f64,
        force: bool,
    ) -> Result<(), ComediError> {
        let code = analog_code(self, self.zero_v + self.volts_per_um_s * velocity_um_s);
        if force || self.last != Some(code) {
            self.last = None;
            device.data_write(self.subdevice, self.channel, self.range_index, code)?;
            self.last = Some(code);
        }
        Ok(())
    }
}

impl Pulse {
    fn stop(&mut self, device: &Device) -> Result<(), ComediError> {
        self.running = None;
        device.disarm(self.config.counter_subdevice)?;
        self.direction_high = None;
        device.dio_write(
            self.config.dio_subdevice,
            self.config.direction_channel,
            false,
        )?;
        self.direction_high = Some(false);
        Ok(())
    }

    fn write(&mut self, device: &Device, velocity_um_s: f64) -> Result<(), ComediError> {
        let s = &self.config;
        let rate_hz = (velocity_um_s.abs() * s.pulses_per_um).min(s.max_rate_hz);
        let Some(ticks) = pulse_ticks(rate_hz).filter(|_| velocity_um_s.is_finite()) else {
            return if self.running.is_some() {
                self.stop(device)
            } else {
                Ok(())
            };
        };
        let high = (velocity_um_s > 0.0) != s.invert_direction;
        let counter = s.counter_subdevice;
        if self.direction_high != Some(high) {
            // Never a pulse with the wrong direction: stop, switch, restart.
            if self.running.take().is_some() {
                device.disarm(counter)?;
            }
            self.direction_high = None;
            device.dio_write(s.dio_subdevice, s.direction_channel, high)?;
            self.direction_high = Some(high);
        }
        match self.running {
            Some(running) if running == ticks => {}
            Some(_) => {
                // Takes effect at the next terminal count; the train keeps running.
                device.data_write(counter, 1, 0, ticks.0)?;
                device.data_write(counter, 2, 0, ticks.1)?;
                self.running = Some(ticks);
            }
            None => {
                device.data_write(counter, 0, 0, ticks.0)?;
                device.data_write(counter, 1, 0, ticks.0)?;
                device.data_write(counter, 2, 0, ticks.1)?;
                device.arm(counter, gpct::ARM_IMMEDIATE)?;
                self.running = Some(ticks);
            }
        }
        Ok(())
    }
}

impl RateOutput for ComediRate {
    fn name(&self) -> &str {
        &self.name
    }

    fn write_velocity(&mut self, _now_s: f64, velocity_um_s: Vector3<f64>) -> Result<(), DaqError> {
        for (axis, &v) in self.axes.iter_mut().zip(velocity_um_s.iter()) {
            match axis {
                Axis::None => Ok(()),
                Axis::Analog(b, a) => a.write(&self.boards[*b], v, false),
                Axis::Pulse(b, p) => p.write(&self.boards[*b], v),
            }
            .map_err(write_error)?;
        }
        Ok(())
    }

    /// Every axis to zero, whatever fails on the way; the first error is returned.
    fn zero(&mut self, _now_s: f64) -> Result<(), DaqError> {
        let mut first = None;
        for axis in &mut self.axes {
            let result = match axis {
                Axis::None => Ok(()),
                Axis::Analog(b, a) => a.write(&self.boards[*b], 0.0, true),
                Axis::Pulse(b, p) => p.stop(&self.boards[*b]),
            };
            if let Err(e) = result {
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), |e| Err(write_error(e)))
    }
}

impl Drop for ComediRate {
    fn drop(&mut self) {
        if let Err(e) = self.zero(0.0) {
            tracing::error!("{}: setting outputs to zero on close: {e}", self.name);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulse_ticks_cover_the_counter() {
        // 1 kHz: 20000 ticks of 50 ns, half high.
        assert_eq!(pulse_ticks(1000.0), Some((10_000, 10_000)));
        assert_eq!(pulse_ticks(3.0e6), Some((4, 3)));
        assert_eq!(pulse_ticks(5.0e6), Some((2, 2)));
        assert_eq!(pulse_ticks(0.0), None);
        assert_eq!(
            pulse_ticks(1.0),
            None,
            "slower than the 24-bit counter can count"
        );
        let (low, high) = pulse_ticks(1.2).unwrap();
        assert!(low + high <= MAX_PERIOD_TICKS);
    }
}
