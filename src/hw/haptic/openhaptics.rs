//! The `"openhaptics"` haptic backend: a PHANToM through the HD API.
//!
//! OpenHaptics runs its own 1 kHz servo thread (the HD scheduler); the daemon's haptic
//! loop runs on another. They meet without blocking either: the servo callback writes
//! each sample (position, velocity, buttons) into a triple buffer and takes the newest
//! force from another; the forces-on request, the servo tick counter and the last HD
//! error are atomics. Neither side ever waits for the other.
//!
//! Safety: forces are off until the daemon enables them, and the callback switches them
//! off itself on any HD error (the daemon must enable them again after the fault).
//! [`HapticDevice::read`] reports that error (comm/device errors as
//! [`HapticError::Lost`], max force/velocity and warm motors as [`HapticError::Device`])
//! and a servo loop that stops ticking as lost, so the daemon's safety rules apply.
use std::ffi::{c_int, c_uint, c_void, CString};
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Vector3;

use super::config::OpenHapticsConfig;
use super::hd_sys::{self as hd, Api, Fault, Hhd};
use super::{HapticDevice, HapticError, HapticSample, SWITCH_BUTTON};

// HD's button masks are the bits of `HapticSample::buttons`: they pass through as read.
const _: () =
    assert!(hd::HD_DEVICE_BUTTON_1 == 1 && hd::HD_DEVICE_BUTTON_2 as u32 == SWITCH_BUTTON);

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Sample {
    position_mm: [f64; 3],
    velocity_mm_s: [f64; 3],
    /// `HD_CURRENT_BUTTONS` as read in the frame.
    buttons: u32,
}

/// What both threads see.
#[derive(Default)]
struct Shared {
    forces_requested: AtomicBool,
    ticks: AtomicU64,
    fault_code: AtomicU32,
    fault_internal: AtomicI32,
}

/// The servo thread's half; the HD scheduler hands the callback a pointer to it.
struct Servo {
    api: Arc<Api>,
    hhd: Hhd,
    shared: Arc<Shared>,
    samples: triple_buffer::Input<Sample>,
    forces: triple_buffer::Output<[f64; 3]>,
    enabled: bool,
}

/// The HD servo callback. It must not panic or allocate: plain calls and stores only.
unsafe extern "C" fn servo_callback(user: *mut c_void) -> c_uint {
    // SAFETY: `user` is the `Servo` that `OpenHaptics` boxed for this callback; it is
    // freed only after the scheduler has stopped and the callback is unscheduled, and
    // only the servo thread touches it meanwhile.
    let servo = unsafe { &mut *user.cast::<Servo>() };
    servo.tick();
    hd::HD_CALLBACK_CONTINUE
}

impl Servo {
    fn tick(&mut self) {
        let api = &*self.api;
        let mut sample = Sample::default();
        let mut buttons: c_int = 0;
        let want = self.shared.forces_requested.load(Ordering::Acquire);
        let force = if want { *self.forces.read() } else { [0.0; 3] };
        // SAFETY: HD calls from the servo thread inside a frame, on arrays of three doubles
        // and on one int for the buttons.
        unsafe {
            (api.begin_frame)(self.hhd);
            (api.get_doublev)(hd::HD_CURRENT_POSITION, sample.position_mm.as_mut_ptr());
            (api.get_doublev)(hd::HD_CURRENT_VELOCITY, sample.velocity_mm_s.as_mut_ptr());
            (api.get_integerv)(hd::HD_CURRENT_BUTTONS, &mut buttons);
            if want != self.enabled {
                if want {
                    (api.enable)(hd::HD_FORCE_OUTPUT);
                } else {
                    (api.disable)(hd::HD_FORCE_OUTPUT);
                }
                self.enabled = want;
            }
            (api.set_doublev)(hd::HD_CURRENT_FORCE, force.as_ptr());
            (api.end_frame)(self.hhd);
        }
        sample.buttons = buttons as u32;
        // SAFETY: reading the error stack; at most a few entries per frame.
        let first = unsafe { (api.get_error)() };
        if first.error_code != hd::HD_SUCCESS {
            for _ in 0..8 {
                // SAFETY: as above (drain what else this frame raised).
                if unsafe { (api.get_error)() }.error_code == hd::HD_SUCCESS {
                    break;
                }
            }
            // Unhealthy: forces off now, and until the daemon asks again.
            self.shared.forces_requested.store(false, Ordering::Release);
            // SAFETY: as above; outside the frame, switching force output off.
            unsafe { (api.disable)(hd::HD_FORCE_OUTPUT) };
            self.enabled = false;
            let shared = &self.shared;
            shared
                .fault_internal
                .store(first.internal_error_code, Ordering::Relaxed);
            shared.fault_code.store(first.error_code, Ordering::Release);
        }
        self.samples.write(sample);
        self.shared.ticks.fetch_add(1, Ordering::Release);
    }
}

/// The boxed servo half, owned through a raw pointer while the scheduler may use it.
struct ServoBox(*mut Servo);
// SAFETY: the pointee is only used by the HD servo thread while scheduled, and freed by
// `OpenHaptics::drop` after unscheduling; moving the owner between threads is fine.
unsafe impl Send for ServoBox {}

pub struct OpenHaptics {
    name: String,
    api: Arc<Api>,
    hhd: Hhd,
    handle: hd::SchedulerHandle,
    shared: Arc<Shared>,
    servo: ServoBox,
    samples: triple_buffer::Output<Sample>,
    forces: triple_buffer::Input<[f64; 3]>,
    stall_s: f64,
    /// (ticks, daemon time when they last advanced)
    last_progress: Option<(u64, f64)>,
}

fn open_error(device: &str, reason: impl std::fmt::Display) -> HapticError {
    HapticError::Open {
        device: device.into(),
        reason: reason.to_string(),
    }
}

impl OpenHaptics {
    /// Loads libHD, initialises the device, starts the servo loop with forces off.
    pub fn open(config: &OpenHapticsConfig) -> Result<OpenHaptics, HapticError> {
        let shown = config.device_name.as_deref().unwrap_or("default device");
        let name = format!("openhaptics:{shown}");
        let api = Api::load(&config.library).map_err(|e| {
            open_error(
                &name,
                format!(
                    "cannot load {}: {e} (is OpenHaptics installed?)",
                    config.library
                ),
            )
        })?;
        let api = Arc::new(api);
        let device_name = match &config.device_name {
            Some(n) => {
                Some(CString::new(n.as_str()).map_err(|_| open_error(&name, "NUL in name"))?)
            }
            None => None,
        };
        let name_ptr = device_name
            .as_ref()
            .map_or(std::ptr::null(), |n| n.as_ptr());
        // SAFETY: a valid C string or NULL (HD_DEFAULT_DEVICE).
        let hhd = unsafe { (api.init_device)(name_ptr) };
        api.check("hdInitDevice")
            .map_err(|e| open_error(&name, e))?;
        if hhd == hd::HD_INVALID_HANDLE {
            return Err(open_error(&name, "hdInitDevice returned no device"));
        }
        // SAFETY: the device is initialised and current; forces stay off until asked for.
        unsafe { (api.disable)(hd::HD_FORCE_OUTPUT) };
        let shared = Arc::new(Shared::default());
        let (sample_in, samples) = triple_buffer::triple_buffer(&Sample::default());
        let (forces, force_out) = triple_buffer::triple_buffer(&[0.0; 3]);
        let servo = Box::into_raw(Box::new(Servo {
            api: api.clone(),
            hhd,
            shared: shared.clone(),
            samples: sample_in,
            forces: force_out,
            enabled: false,
        }));
        // SAFETY: the callback and its data stay valid until Drop unschedules it.
        let handle = unsafe {
            (api.schedule_asynchronous)(
                servo_callback,
                servo.cast(),
                hd::HD_DEFAULT_SCHEDULER_PRIORITY,
            )
        };
        let mut device = OpenHaptics {
            name,
            api: api.clone(),
            hhd,
            handle,
            shared,
            servo: ServoBox(servo),
            samples,
            forces,
            stall_s: config.stall_ms as f64 * 1e-3,
            last_progress: None,
        };
        // SAFETY: starts HD's servo thread, which calls our callback.
        unsafe { (api.start_scheduler)() };
        api.check("hdStartScheduler")
            .map_err(|e| open_error(&device.name, e))?;
        let first_tick = Duration::from_secs_f64((4.0 * device.stall_s).max(0.2));
        if !device.wait_ticks(1, first_tick) {
            return Err(open_error(&device.name, "the servo loop did not start"));
        }
        device.samples.update();
        Ok(device)
    }

    /// Waits (bounded) until the servo loop has ticked `n` more times.
    fn wait_ticks(&self, n: u64, limit: Duration) -> bool {
        let start = self.shared.ticks.load(Ordering::Acquire);
        let began = Instant::now();
        while self.shared.ticks.load(Ordering::Acquire) < start + n {
            if began.elapsed() > limit {
                return false;
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        true
    }

    fn fault(&self, code: c_uint) -> HapticError {
        let internal = self.shared.fault_internal.load(Ordering::Relaxed);
        let reason = format!(
            "{} ({}; HD error 0x{code:04x}, device code {internal}); forces switched off",
            hd::describe(code),
            self.api.error_string(code)
        );
        let device = self.name.clone();
        match Fault::of(code) {
            Fault::Lost => HapticError::Lost { device, reason },
            Fault::Force | Fault::Other => HapticError::Device { device, reason },
        }
    }
}

impl HapticDevice for OpenHaptics {
    fn name(&self) -> &str {
        &self.name
    }

    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError> {
        let code = self.shared.fault_code.swap(0, Ordering::AcqRel);
        if code != hd::HD_SUCCESS {
            return Err(self.fault(code));
        }
        let ticks = self.shared.ticks.load(Ordering::Acquire);
        match self.last_progress {
            Some((seen, since_s)) if seen == ticks => {
                if now_s - since_s > self.stall_s {
                    return Err(HapticError::Lost {
                        device: self.name.clone(),
                        reason: format!(
                            "the servo loop has not ticked for {:.0} ms",
                            (now_s - since_s) * 1e3
                        ),
                    });
                }
            }
            _ => self.last_progress = Some((ticks, now_s)),
        }
        let s = self.samples.read();
        Ok(HapticSample {
            position_mm: Vector3::from(s.position_mm),
            velocity_mm_s: Vector3::from(s.velocity_mm_s),
            buttons: s.buttons,
        })
    }

    fn write_force(&mut self, force_n: Vector3<f64>) -> Result<(), HapticError> {
        let f = if force_n.iter().all(|v| v.is_finite()) {
            force_n.into()
        } else {
            [0.0; 3]
        };
        self.forces.write(f);
        Ok(())
    }

    fn set_forces_enabled(&mut self, enabled: bool) -> Result<(), HapticError> {
        if !enabled {
            self.forces.write([0.0; 3]);
        }
        self.shared
            .forces_requested
            .store(enabled, Ordering::Release);
        Ok(())
    }
}

impl Drop for OpenHaptics {
    fn drop(&mut self) {
        self.forces.write([0.0; 3]);
        self.shared.forces_requested.store(false, Ordering::Release);
        // Let the servo loop render zero and switch force output off (bounded wait).
        let _ = self.wait_ticks(2, Duration::from_millis(50));
        // SAFETY: stop the servo thread, then remove our callback and release the device;
        // after this nothing calls `servo_callback`, so its box can be freed.
        unsafe {
            (self.api.stop_scheduler)();
            (self.api.unschedule)(self.handle);
            (self.api.disable)(hd::HD_FORCE_OUTPUT);
            (self.api.disable_device)(self.hhd);
            drop(Box::from_raw(self.servo.0));
        }
        let _ = self.api.check("closing");
    }
}
