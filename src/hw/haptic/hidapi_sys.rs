//! hidapi bindings (the hidraw flavour, `libhidapi-hidraw.so.0`; apt: libhidapi-dev to
//! build, libhidapi-hidraw0 to run): only what the HID backend and `probe-devices` use.
//! Written by hand rather than taken from hidapi-rs, whose 2.6 release links symbols
//! of hidapi 0.14 (`hid_send_output_report`, `hid_get_report_descriptor`) that Debian
//! 12's hidapi 0.13.1 does not have.
//!
//! [`Device`] owns an open `hid_device *` and closes it on drop; `Device::check` is the
//! one place a hidapi status becomes an error (with `hid_error`'s message).
use std::ffi::{c_char, c_int, c_uchar, c_ushort, CStr};
use std::ptr::NonNull;

#[repr(C)]
struct HidDevice {
    _opaque: [u8; 0],
}

#[repr(C)]
struct DeviceInfo {
    path: *mut c_char,
    vendor_id: c_ushort,
    product_id: c_ushort,
    serial_number: *mut libc::wchar_t,
    release_number: c_ushort,
    manufacturer_string: *mut libc::wchar_t,
    product_string: *mut libc::wchar_t,
    usage_page: c_ushort,
    usage: c_ushort,
    interface_number: c_int,
    next: *mut DeviceInfo,
}

#[link(name = "hidapi-hidraw")]
extern "C" {
    fn hid_init() -> c_int;
    fn hid_enumerate(vendor_id: c_ushort, product_id: c_ushort) -> *mut DeviceInfo;
    fn hid_free_enumeration(devs: *mut DeviceInfo);
    fn hid_open(
        vendor_id: c_ushort,
        product_id: c_ushort,
        serial: *const libc::wchar_t,
    ) -> *mut HidDevice;
    fn hid_read_timeout(dev: *mut HidDevice, data: *mut c_uchar, length: usize, ms: c_int)
        -> c_int;
    fn hid_write(dev: *mut HidDevice, data: *const c_uchar, length: usize) -> c_int;
    fn hid_error(dev: *mut HidDevice) -> *const libc::wchar_t;
    fn hid_close(dev: *mut HidDevice);
}

/// A hidapi call that failed.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{call} failed: {message}")]
pub struct HidError {
    pub call: &'static str,
    pub message: String,
}

/// A HID device hidapi can see.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    pub path: String,
    pub vendor_id: u16,
    pub product_id: u16,
    pub product: String,
}

fn wide(ptr: *const libc::wchar_t) -> Option<String> {
    if ptr.is_null() {
        return None;
    }
    let mut out = String::new();
    for i in 0.. {
        // SAFETY: a NUL-terminated wide string from hidapi; we stop at the NUL.
        let c = unsafe { *ptr.add(i) };
        if c == 0 {
            break;
        }
        out.push(char::from_u32(c as u32).unwrap_or('?'));
    }
    Some(out)
}

/// Initialises hidapi (idempotent).
pub fn init() -> Result<(), HidError> {
    // SAFETY: no arguments; hidapi guards against double initialisation.
    if unsafe { hid_init() } < 0 {
        return Err(HidError {
            call: "hid_init",
            message: "hidapi could not initialise".into(),
        });
    }
    Ok(())
}

/// Every HID device hidapi can see (vendor/product 0 = all).
pub fn enumerate() -> Result<Vec<Found>, HidError> {
    init()?;
    let mut found = Vec::new();
    // SAFETY: hid_enumerate returns a list we walk and then free exactly once.
    unsafe {
        let head = hid_enumerate(0, 0);
        let mut node = head;
        while let Some(info) = node.as_ref() {
            let path = if info.path.is_null() {
                String::new()
            } else {
                CStr::from_ptr(info.path).to_string_lossy().into_owned()
            };
            found.push(Found {
                path,
                vendor_id: info.vendor_id,
                product_id: info.product_id,
                product: wide(info.product_string).unwrap_or_default(),
            });
            node = info.next;
        }
        hid_free_enumeration(head);
    }
    Ok(found)
}

/// An open HID device.
pub struct Device {
    raw: NonNull<HidDevice>,
}

// SAFETY: a hid_device is a file descriptor and buffers; hidapi does not tie it to a
// thread. The backend uses it from the haptic loop's thread only (not Sync).
unsafe impl Send for Device {}

impl Device {
    pub fn open(vendor_id: u16, product_id: u16) -> Result<Device, HidError> {
        init()?;
        // SAFETY: NULL serial: the first device with these ids.
        let raw = unsafe { hid_open(vendor_id, product_id, std::ptr::null()) };
        NonNull::new(raw)
            .map(|raw| Device { raw })
            .ok_or_else(|| HidError {
                call: "hid_open",
                // SAFETY: hid_error(NULL) describes the last open failure (or returns NULL).
                message: wide(unsafe { hid_error(std::ptr::null_mut()) }).unwrap_or_else(|| {
                    "no such device, or no permission on its hidraw node".into()
                }),
            })
    }

    /// The one place a hidapi status becomes an error: negative means failed.
    fn check(&self, status: c_int, call: &'static str) -> Result<usize, HidError> {
        if status >= 0 {
            return Ok(status as usize);
        }
        // SAFETY: valid handle; the message is copied at once.
        let message =
            wide(unsafe { hid_error(self.raw.as_ptr()) }).unwrap_or_else(|| "unknown error".into());
        Err(HidError { call, message })
    }

    /// One input report into `buf`, waiting at most `timeout_ms` (0: do not wait).
    /// Returns its length; 0 when none was pending.
    pub fn read_timeout(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, HidError> {
        // SAFETY: valid handle and a buffer of the given length.
        let n =
            unsafe { hid_read_timeout(self.raw.as_ptr(), buf.as_mut_ptr(), buf.len(), timeout_ms) };
        self.check(n, "hid_read_timeout")
    }

    /// One output report (its first byte is the report id).
    pub fn write(&mut self, report: &[u8]) -> Result<usize, HidError> {
        // SAFETY: valid handle and a buffer of the given length.
        let n = unsafe { hid_write(self.raw.as_ptr(), report.as_ptr(), report.len()) };
        self.check(n, "hid_write")
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: we own the handle and close it exactly once.
        unsafe { hid_close(self.raw.as_ptr()) };
    }
}
