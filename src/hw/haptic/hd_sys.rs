//! OpenHaptics HD API bindings, loaded at run time from `libHD.so` with libloading (as
//! CHAI3D loads its device libraries), so building needs no vendor SDK and a machine
//! without OpenHaptics only fails when the PHANToM backend is opened.
//!
//! Types and constants follow OpenHaptics' `hdDefines.h` / `hdScheduler.h`. [`Api::check`]
//! is the one place an HD error becomes a Rust error; [`Fault::of`] classifies the error
//! codes the servo callback sees (the callback itself must not allocate).
use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void, CStr};

use libloading::Library;

pub type Hhd = c_uint;
pub type SchedulerHandle = c_ulong;
pub type Callback = unsafe extern "C" fn(*mut c_void) -> c_uint;

/// `HDErrorInfo`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorInfo {
    pub error_code: c_uint,
    pub internal_error_code: c_int,
    pub hhd: Hhd,
}

pub const HD_SUCCESS: c_uint = 0x0000;
pub const HD_WARM_MOTORS: c_uint = 0x0200;
pub const HD_EXCEEDED_MAX_FORCE: c_uint = 0x0201;
pub const HD_EXCEEDED_MAX_FORCE_IMPULSE: c_uint = 0x0202;
pub const HD_EXCEEDED_MAX_VELOCITY: c_uint = 0x0203;
pub const HD_FORCE_ERROR: c_uint = 0x0204;
pub const HD_DEVICE_FAULT: c_uint = 0x0300;
pub const HD_COMM_ERROR: c_uint = 0x0302;
pub const HD_COMM_CONFIG_ERROR: c_uint = 0x0303;
pub const HD_TIMER_ERROR: c_uint = 0x0304;

/// The buttons held down (`HDint`), one bit each: `HD_DEVICE_BUTTON_1` (the front
/// button) is bit 0, `HD_DEVICE_BUTTON_2` bit 1.
pub const HD_CURRENT_BUTTONS: c_uint = 0x2000;
pub const HD_DEVICE_BUTTON_1: c_int = 1 << 0;
pub const HD_DEVICE_BUTTON_2: c_int = 1 << 1;
pub const HD_CURRENT_POSITION: c_uint = 0x2050;
pub const HD_CURRENT_VELOCITY: c_uint = 0x2051;
pub const HD_CURRENT_FORCE: c_uint = 0x2700;
pub const HD_FORCE_OUTPUT: c_uint = 0x4000;
pub const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
pub const HD_CALLBACK_CONTINUE: c_uint = 1;
pub const HD_DEFAULT_SCHEDULER_PRIORITY: c_ushort = u16::MAX / 2;

/// What an HD error means for the daemon.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The device or its link is gone (communication, device or timer fault).
    Lost,
    /// A force safety limit tripped (max force/velocity, warm motors); the device is there.
    Force,
    /// Anything else (a programming or licensing error).
    Other,
}

impl Fault {
    pub fn of(code: c_uint) -> Fault {
        match code {
            HD_COMM_ERROR | HD_COMM_CONFIG_ERROR | HD_DEVICE_FAULT | HD_TIMER_ERROR => Fault::Lost,
            HD_WARM_MOTORS
            | HD_EXCEEDED_MAX_FORCE
            | HD_EXCEEDED_MAX_FORCE_IMPULSE
            | HD_EXCEEDED_MAX_VELOCITY
            | HD_FORCE_ERROR => Fault::Force,
            _ => Fault::Other,
        }
    }
}

/// Our words for the codes the daemon reacts to (the library's string follows).
pub fn describe(code: c_uint) -> &'static str {
    match code {
        HD_COMM_ERROR => "communication error (cable, power or the device's link)",
        HD_COMM_CONFIG_ERROR => "communication configuration error (unknown device name?)",
        HD_DEVICE_FAULT => "device fault",
        HD_TIMER_ERROR => "servo timer error",
        HD_WARM_MOTORS => "motors too warm: forces off until they cool",
        HD_EXCEEDED_MAX_FORCE => "maximum force exceeded",
        HD_EXCEEDED_MAX_FORCE_IMPULSE => "maximum force impulse exceeded",
        HD_EXCEEDED_MAX_VELOCITY => "maximum velocity exceeded",
        HD_FORCE_ERROR => "force error",
        _ => "HD error",
    }
}

/// The HD functions nanoforce calls; the library stays loaded as long as this lives.
pub struct Api {
    pub init_device: unsafe extern "C" fn(*const c_char) -> Hhd,
    pub disable_device: unsafe extern "C" fn(Hhd),
    pub get_error: unsafe extern "C" fn() -> ErrorInfo,
    pub get_error_string: unsafe extern "C" fn(c_uint) -> *const c_char,
    pub begin_frame: unsafe extern "C" fn(Hhd),
    pub end_frame: unsafe extern "C" fn(Hhd),
    pub get_doublev: unsafe extern "C" fn(c_uint, *mut f64),
    pub get_integerv: unsafe extern "C" fn(c_uint, *mut c_int),
    pub set_doublev: unsafe extern "C" fn(c_uint, *const f64),
    pub enable: unsafe extern "C" fn(c_uint),
    pub disable: unsafe extern "C" fn(c_uint),
    pub schedule_asynchronous:
        unsafe extern "C" fn(Callback, *mut c_void, c_ushort) -> SchedulerHandle,
    pub unschedule: unsafe extern "C" fn(SchedulerHandle),
    pub start_scheduler: unsafe extern "C" fn(),
    pub stop_scheduler: unsafe extern "C" fn(),
    _library: Library,
}

/// An HD call that failed.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{call}: {meaning} ({library}; HD error 0x{code:04x}, device code {internal})")]
pub struct HdError {
    pub call: &'static str,
    pub code: c_uint,
    pub internal: c_int,
    pub meaning: &'static str,
    pub library: String,
}

impl Api {
    /// Loads `library` (a name for the dynamic linker to search, or a path).
    pub fn load(library: &str) -> Result<Api, String> {
        // SAFETY: loading runs the library's initialisers; libHD's are the vendor's own
        // and do not depend on anything we hold.
        let lib = unsafe { Library::new(library) }.map_err(|e| e.to_string())?;
        macro_rules! sym {
            ($name:literal) => {
                // SAFETY: the symbol has the type hdDefines/hd.h declares for it; the
                // pointer is used only while `_library` keeps the library loaded.
                *unsafe { lib.get(concat!($name, "\0").as_bytes()) }
                    .map_err(|e| format!("{library}: {e}"))?
            };
        }
        Ok(Api {
            init_device: sym!("hdInitDevice"),
            disable_device: sym!("hdDisableDevice"),
            get_error: sym!("hdGetError"),
            get_error_string: sym!("hdGetErrorString"),
            begin_frame: sym!("hdBeginFrame"),
            end_frame: sym!("hdEndFrame"),
            get_doublev: sym!("hdGetDoublev"),
            get_integerv: sym!("hdGetIntegerv"),
            set_doublev: sym!("hdSetDoublev"),
            enable: sym!("hdEnable"),
            disable: sym!("hdDisable"),
            schedule_asynchronous: sym!("hdScheduleAsynchronous"),
            unschedule: sym!("hdUnschedule"),
            start_scheduler: sym!("hdStartScheduler"),
            stop_scheduler: sym!("hdStopScheduler"),
            _library: lib,
        })
    }

    /// The library's description of an error code.
    pub fn error_string(&self, code: c_uint) -> String {
        // SAFETY: hdGetErrorString returns a static string or NULL; we copy it at once.
        let text = unsafe { (self.get_error_string)(code) };
        if text.is_null() {
            "no description".into()
        } else {
            // SAFETY: non-null, NUL-terminated (the library's static table).
            unsafe { CStr::from_ptr(text) }
                .to_string_lossy()
                .into_owned()
        }
    }

    /// The one place an HD error becomes a Rust error: pops the error stack after
    /// `call` and fails with its first error, if any.
    pub fn check(&self, call: &'static str) -> Result<(), HdError> {
        let mut first: Option<ErrorInfo> = None;
        for _ in 0..16 {
            // SAFETY: hdGetError only reads the library's error stack.
            let info = unsafe { (self.get_error)() };
            if info.error_code == HD_SUCCESS {
                break;
            }
            first.get_or_insert(info);
        }
        match first {
            None => Ok(()),
            Some(info) => Err(HdError {
                call,
                code: info.error_code,
                internal: info.internal_error_code,
                meaning: describe(info.error_code),
                library: self.error_string(info.error_code),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_classify_as_the_daemon_needs() {
        assert_eq!(Fault::of(HD_COMM_ERROR), Fault::Lost);
        assert_eq!(Fault::of(HD_DEVICE_FAULT), Fault::Lost);
        assert_eq!(Fault::of(HD_EXCEEDED_MAX_FORCE), Fault::Force);
        assert_eq!(Fault::of(HD_EXCEEDED_MAX_VELOCITY), Fault::Force);
        assert_eq!(Fault::of(HD_WARM_MOTORS), Fault::Force);
        assert_eq!(Fault::of(0x0100), Fault::Other);
        assert_eq!(HD_DEFAULT_SCHEDULER_PRIORITY, 32767);
    }

    #[test]
    fn a_missing_library_is_an_error_not_a_panic() {
        let err = Api::load("/nonexistent/libHD.so").err().unwrap();
        assert!(err.contains("/nonexistent/libHD.so"), "{err}");
    }
}
