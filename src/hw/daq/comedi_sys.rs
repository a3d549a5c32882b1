//! comedilib bindings: only the functions nanoforce uses, declared by hand (there is no
//! comedi crate, and bindgen would need libclang). Linked against `libcomedi.so.0`
//! (apt: libcomedi-dev to build, libcomedi0 to run).
//!
//! [`Device`] is the safe wrapper: every call goes through `Device::check`, the one
//! place a C status becomes a [`ComediError`] (with `comedi_errno`/`comedi_strerror`),
//! and dropping it closes the device. Setting outputs to zero on drop is the job of
//! the rate output that owns the device ([`super::comedi::ComediRate`]), which knows
//! what zero means for each channel.
use std::ffi::{c_char, c_int, c_uint, CStr, CString};
use std::path::Path;
use std::ptr::NonNull;

#[repr(C)]
struct ComediT {
    _opaque: [u8; 0],
}

/// A row of a channel's range table (`comedi_range`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub min: f64,
    pub max: f64,
    pub unit: c_uint,
}

pub const UNIT_VOLT: c_uint = 0;
pub const AREF_GROUND: c_uint = 0;
pub const COMEDI_OUTPUT: c_uint = 1;
pub const CR_EDGE: c_uint = 0x4000_0000;

/// `enum comedi_subdevice_type`.
pub const SUBD_AO: i32 = 2;
pub const SUBD_DO: i32 = 4;
pub const SUBD_DIO: i32 = 5;
pub const SUBD_COUNTER: i32 = 6;

/// NI general-purpose counter settings (comedi.h), for a continuous pulse train.
pub mod gpct {
    pub const COUNTING_MODE_NORMAL: u32 = 0;
    pub const OUTPUT_TC_TOGGLE: u32 = 0x200;
    pub const LOADING_ON_TC: u32 = 0x1000;
    pub const RELOAD_SOURCE_SWITCHING: u32 = 0x400_0000;
    pub const COUNTING_DIRECTION_DOWN: u32 = 0;
    pub const LOAD_B_SELECT: u32 = 0x80;
    pub const STOP_ON_GATE: u32 = 0;
    pub const NO_HARDWARE_DISARM: u32 = 0;
    /// The 20 MHz timebase.
    pub const TIMEBASE_1_CLOCK_SRC: u32 = 0;
    pub const TIMEBASE_1_PERIOD_NS: u32 = 50;
    pub const DISABLED_GATE_SELECT: u32 = 0x8000;
    pub const ARM_IMMEDIATE: u32 = 0;
    /// Toggle on terminal count, reload alternately from A (low time) and B (high).
    pub const PULSE_TRAIN_MODE: u32 = COUNTING_MODE_NORMAL
        | OUTPUT_TC_TOGGLE
        | LOADING_ON_TC
        | RELOAD_SOURCE_SWITCHING
        | COUNTING_DIRECTION_DOWN
        | LOAD_B_SELECT
        | STOP_ON_GATE
        | NO_HARDWARE_DISARM;
}

#[link(name = "comedi")]
extern "C" {
    fn comedi_open(path: *const c_char) -> *mut ComediT;
    fn comedi_close(it: *mut ComediT) -> c_int;
    fn comedi_errno() -> c_int;
    fn comedi_strerror(errnum: c_int) -> *const c_char;
    fn comedi_get_board_name(it: *mut ComediT) -> *const c_char;
    fn comedi_get_driver_name(it: *mut ComediT) -> *const c_char;
    fn comedi_get_n_subdevices(it: *mut ComediT) -> c_int;
    fn comedi_get_subdevice_type(it: *mut ComediT, subd: c_uint) -> c_int;
    fn comedi_get_n_channels(it: *mut ComediT, subd: c_uint) -> c_int;
    fn comedi_get_maxdata(it: *mut ComediT, subd: c_uint, chan: c_uint) -> c_uint;
    fn comedi_get_range(it: *mut ComediT, subd: c_uint, chan: c_uint, r: c_uint) -> *mut Range;
    fn comedi_find_range(
        it: *mut ComediT,
        subd: c_uint,
        chan: c_uint,
        unit: c_uint,
        min: f64,
        max: f64,
    ) -> c_int;
    fn comedi_from_phys(data: f64, range: *const Range, maxdata: c_uint) -> c_uint;
    fn comedi_data_write(
        it: *mut ComediT,
        subd: c_uint,
        chan: c_uint,
        range: c_uint,
        aref: c_uint,
        data: c_uint,
    ) -> c_int;
    fn comedi_dio_config(it: *mut ComediT, subd: c_uint, chan: c_uint, dir: c_uint) -> c_int;
    fn comedi_dio_write(it: *mut ComediT, subd: c_uint, chan: c_uint, bit: c_uint) -> c_int;
    fn comedi_reset(it: *mut ComediT, subd: c_uint) -> c_int;
    fn comedi_arm(it: *mut ComediT, subd: c_uint, source: c_uint) -> c_int;
    fn comedi_disarm(it: *mut ComediT, subd: c_uint) -> c_int;
    fn comedi_set_counter_mode(it: *mut ComediT, subd: c_uint, chan: c_uint, mode: c_uint)
        -> c_int;
    fn comedi_set_clock_source(
        it: *mut ComediT,
        subd: c_uint,
        chan: c_uint,
        clock: c_uint,
        period_ns: c_uint,
    ) -> c_int;
    fn comedi_set_gate_source(
        it: *mut ComediT,
        subd: c_uint,
        chan: c_uint,
        gate: c_uint,
        source: c_uint,
    ) -> c_int;
}

/// A comedilib call that failed.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{device}: {call} failed: {message}")]
pub struct ComediError {
    pub device: String,
    pub call: &'static str,
    pub message: String,
}

/// An open comedi device (`comedi_t *`); closed on drop.
pub struct Device {
    raw: NonNull<ComediT>,
    path: String,
}

// SAFETY: a comedi_t is a file descriptor and a little state; comedilib does not tie it
// to the opening thread. `Device` is moved to the haptic loop thread and used from there
// only (it is not Sync).
unsafe impl Send for Device {}

/// comedilib's message for its last error.
fn last_error() -> String {
    // SAFETY: comedi_errno reads a thread-local; comedi_strerror returns a pointer to a
    // static string (or NULL), which we copy at once.
    unsafe {
        let errnum = comedi_errno();
        let text = comedi_strerror(errnum);
        if text.is_null() {
            format!("comedi error {errnum}")
        } else {
            CStr::from_ptr(text).to_string_lossy().into_owned()
        }
    }
}

impl Device {
    pub fn open(path: &Path) -> Result<Device, ComediError> {
        let shown = path.display().to_string();
        let error = |message: String| ComediError {
            device: shown.clone(),
            call: "comedi_open",
            message,
        };
        let c_path = CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| error("the path contains a NUL byte".into()))?;
        // SAFETY: a valid C string; comedi_open returns NULL or a handle we own.
        let raw = unsafe { comedi_open(c_path.as_ptr()) };
        match NonNull::new(raw) {
            Some(raw) => Ok(Device { raw, path: shown }),
            None => Err(error(last_error())),
        }
    }

    pub fn path(&self) -> &str {
        &self.path
    }

    /// The one place a comedilib status becomes an error: negative means failed.
    fn check(&self, status: c_int, call: &'static str) -> Result<u32, ComediError> {
        if status >= 0 {
            Ok(status as u32)
        } else {
            Err(ComediError {
                device: self.path.clone(),
                call,
                message: last_error(),
            })
        }
    }

    fn text(&self, ptr: *const c_char) -> String {
        if ptr.is_null() {
            "?".into()
        } else {
            // SAFETY: comedilib returns pointers to strings it keeps while the device is open.
            unsafe { CStr::from_ptr(ptr) }
                .to_string_lossy()
                .into_owned()
        }
    }

    pub fn board_name(&self) -> String {
        // SAFETY: valid handle.
        self.text(unsafe { comedi_get_board_name(self.raw.as_ptr()) })
    }

    pub fn driver_name(&self) -> String {
        // SAFETY: valid handle.
        self.text(unsafe { comedi_get_driver_name(self.raw.as_ptr()) })
    }

    pub fn n_subdevices(&self) -> Result<u32, ComediError> {
        // SAFETY: valid handle.
        let n = unsafe { comedi_get_n_subdevices(self.raw.as_ptr()) };
        self.check(n, "comedi_get_n_subdevices")
    }

    pub fn subdevice_type(&self, subd: u32) -> Result<i32, ComediError> {
        // SAFETY: valid handle; comedilib checks the index.
        let t = unsafe { comedi_get_subdevice_type(self.raw.as_ptr(), subd) };
        self.check(t, "comedi_get_subdevice_type").map(|t| t as i32)
    }

    pub fn n_channels(&self, subd: u32) -> Result<u32, ComediError> {
        // SAFETY: valid handle; comedilib checks the index.
        let n = unsafe { comedi_get_n_channels(self.raw.as_ptr(), subd) };
        self.check(n, "comedi_get_n_channels")
    }

    pub fn maxdata(&self, subd: u32, chan: u32) -> Result<u32, ComediError> {
        // SAFETY: valid handle; comedilib checks the indices (0 means failure).
        let max = unsafe { comedi_get_maxdata(self.raw.as_ptr(), subd, chan) };
        self.check(if max == 0 { -1 } else { 0 }, "comedi_get_maxdata")?;
        Ok(max)
    }

    pub fn range(&self, subd: u32, chan: u32, index: u32) -> Result<Range, ComediError> {
        // SAFETY: valid handle; the returned row lives as long as the device, and we copy it.
        let row = unsafe { comedi_get_range(self.raw.as_ptr(), subd, chan, index) };
        self.check(if row.is_null() { -1 } else { 0 }, "comedi_get_range")?;
        // SAFETY: checked non-null above.
        Ok(unsafe { *row })
    }

    /// The index of the smallest range holding `[min_v, max_v]` volts.
    pub fn find_range(
        &self,
        subd: u32,
        chan: u32,
        min_v: f64,
        max_v: f64,
    ) -> Result<u32, ComediError> {
        // SAFETY: valid handle.
        let r =
            unsafe { comedi_find_range(self.raw.as_ptr(), subd, chan, UNIT_VOLT, min_v, max_v) };
        self.check(r, "comedi_find_range")
    }

    /// Physical value to a raw sample through a range row (comedilib's conversion).
    pub fn from_phys(value: f64, range: &Range, maxdata: u32) -> u32 {
        // SAFETY: a pure function of its arguments; the row is a valid comedi_range.
        unsafe { comedi_from_phys(value, range, maxdata) }
    }

    pub fn data_write(
        &self,
        subd: u32,
        chan: u32,
        range: u32,
        data: u32,
    ) -> Result<(), ComediError> {
        // SAFETY: valid handle; one instruction, no buffers.
        let s =
            unsafe { comedi_data_write(self.raw.as_ptr(), subd, chan, range, AREF_GROUND, data) };
        self.check(s, "comedi_data_write").map(drop)
    }

    pub fn dio_config_output(&self, subd: u32, chan: u32) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_dio_config(self.raw.as_ptr(), subd, chan, COMEDI_OUTPUT) };
        self.check(s, "comedi_dio_config").map(drop)
    }

    pub fn dio_write(&self, subd: u32, chan: u32, high: bool) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_dio_write(self.raw.as_ptr(), subd, chan, u32::from(high)) };
        self.check(s, "comedi_dio_write").map(drop)
    }

    pub fn reset(&self, subd: u32) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_reset(self.raw.as_ptr(), subd) };
        self.check(s, "comedi_reset").map(drop)
    }

    pub fn arm(&self, subd: u32, source: u32) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_arm(self.raw.as_ptr(), subd, source) };
        self.check(s, "comedi_arm").map(drop)
    }

    pub fn disarm(&self, subd: u32) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_disarm(self.raw.as_ptr(), subd) };
        self.check(s, "comedi_disarm").map(drop)
    }

    pub fn set_counter_mode(&self, subd: u32, chan: u32, mode: u32) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_set_counter_mode(self.raw.as_ptr(), subd, chan, mode) };
        self.check(s, "comedi_set_counter_mode").map(drop)
    }

    pub fn set_clock_source(
        &self,
        subd: u32,
        chan: u32,
        clock: u32,
        period_ns: u32,
    ) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_set_clock_source(self.raw.as_ptr(), subd, chan, clock, period_ns) };
        self.check(s, "comedi_set_clock_source").map(drop)
    }

    pub fn set_gate_source(
        &self,
        subd: u32,
        chan: u32,
        gate: u32,
        source: u32,
    ) -> Result<(), ComediError> {
        // SAFETY: valid handle.
        let s = unsafe { comedi_set_gate_source(self.raw.as_ptr(), subd, chan, gate, source) };
        self.check(s, "comedi_set_gate_source").map(drop)
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: we own the handle and close it exactly once; a failure is not actionable.
        let _ = unsafe { comedi_close(self.raw.as_ptr()) };
    }
}
