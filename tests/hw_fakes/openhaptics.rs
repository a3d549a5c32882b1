//! The openhaptics backend against a fake libHD.so with its own 1 kHz servo thread:
//! init by name, samples and buttons in, forces out only while enabled and healthy, HD
//! errors mapped to the daemon's errors, a stalled servo loop reported as lost, and a
//! clean shutdown. One test: the fake's state is per process.
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use nanoforce::hw::haptic::config::OpenHapticsConfig;
use nanoforce::hw::haptic::openhaptics::OpenHaptics;
use nanoforce::hw::haptic::{HapticDevice, HapticError, SWITCH_BUTTON};

use super::support::build;

struct Fake {
    lib: libloading::Library,
}

impl Fake {
    fn call<T: Copy>(&self, name: &str) -> T {
        // SAFETY: the test hooks of tests/fakes/fake_hd.c, with these signatures.
        *unsafe { self.lib.get::<T>(name.as_bytes()) }.unwrap()
    }
    fn set_stylus(&self, p: [f64; 3], v: [f64; 3]) {
        let f: unsafe extern "C" fn(*const f64, *const f64) = self.call("fake_hd_set_stylus");
        // SAFETY: two arrays of three doubles.
        unsafe { f(p.as_ptr(), v.as_ptr()) }
    }
    fn set_buttons(&self, buttons: i32) {
        let f: unsafe extern "C" fn(i32) = self.call("fake_hd_set_buttons");
        // SAFETY: plain value.
        unsafe { f(buttons) }
    }
    fn raise(&self, code: u32) {
        let f: unsafe extern "C" fn(u32, i32) = self.call("fake_hd_raise");
        // SAFETY: plain values.
        unsafe { f(code, 7) }
    }
    fn pause(&self, on: bool) {
        let f: unsafe extern "C" fn(i32) = self.call("fake_hd_pause");
        // SAFETY: plain value.
        unsafe { f(i32::from(on)) }
    }
    fn rendered(&self) -> [f64; 3] {
        let f: unsafe extern "C" fn(*mut f64) = self.call("fake_hd_rendered_force");
        let mut out = [f64::NAN; 3];
        // SAFETY: an array of three doubles.
        unsafe { f(out.as_mut_ptr()) };
        out
    }
    /// (force output, scheduler running, device initialised, callback scheduled)
    fn state(&self) -> (bool, bool, bool, bool) {
        let f: unsafe extern "C" fn() -> i32 = self.call("fake_hd_state");
        // SAFETY: no arguments.
        let s = unsafe { f() };
        (s & 1 != 0, s & 2 != 0, s & 4 != 0, s & 8 != 0)
    }
}

/// The first error `read` gives within a second (the servo thread records it).
fn first_error(mut read: impl FnMut() -> Result<(), HapticError>) -> HapticError {
    let start = Instant::now();
    loop {
        if let Err(e) = read() {
            return e;
        }
        assert!(
            start.elapsed() < Duration::from_secs(1),
            "no error reported"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Polls `cond` for up to a second.
fn eventually(what: &str, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < Duration::from_secs(1), "never: {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn config(library: &str, device_name: Option<&str>) -> OpenHapticsConfig {
    OpenHapticsConfig {
        library: library.into(),
        device_name: device_name.map(str::to_string),
        stall_ms: 50,
    }
}

#[test]
fn phantom_through_a_fake_libhd() {
    let path = build("fake_hd.c", "libHD.so", &["-lpthread"]);
    let path = path.to_str().unwrap();
    // SAFETY: our fake; the backend loads the same file, so both share its state.
    let fake = Fake {
        lib: unsafe { libloading::Library::new(path) }.unwrap(),
    };

    // Opening: an unknown device name and a missing library are clear errors.
    let err = OpenHaptics::open(&config(path, Some("Left PHANToM")))
        .err()
        .unwrap();
    let msg = err.to_string();
    assert!(
        msg.starts_with("openhaptics:Left PHANToM: cannot open: hdInitDevice: communication configuration error")
            && msg.contains("HD error 0x0303"),
        "{msg}"
    );
    let err = OpenHaptics::open(&config("/nonexistent/libHD.so", None))
        .err()
        .unwrap();
    assert!(
        err.to_string()
            .contains("cannot load /nonexistent/libHD.so"),
        "{err}"
    );

    let mut dev = OpenHaptics::open(&config(path, Some("Default PHANToM"))).unwrap();
    assert_eq!(dev.name(), "openhaptics:Default PHANToM");
    assert_eq!(
        fake.state(),
        (false, true, true, true),
        "forces off until enabled"
    );

    // Samples come from the servo thread.
    fake.set_stylus([1.5, -2.0, 30.25], [10.0, 0.0, -4.0]);
    let t0 = Instant::now();
    let now = |t: Instant| t.duration_since(t0).as_secs_f64();
    eventually("the sample arrives", || {
        dev.read(now(Instant::now())).unwrap().position_mm == Vector3::new(1.5, -2.0, 30.25)
    });
    let s = dev.read(now(Instant::now())).unwrap();
    assert_eq!(s.velocity_mm_s, Vector3::new(10.0, 0.0, -4.0));
    assert_eq!(s.buttons, 0, "no button held");

    // Both PHANToM buttons, as HD_CURRENT_BUTTONS gives them: the same bits.
    let mut buttons = || dev.read(now(Instant::now())).unwrap().buttons;
    fake.set_buttons(0b11);
    eventually("both buttons", || buttons() == 0b11);
    fake.set_buttons(0b01);
    eventually("the front button", || buttons() == 0b01);
    fake.set_buttons(0b10);
    eventually("the switch button", || buttons() == SWITCH_BUTTON);
    fake.set_buttons(0);
    eventually("released", || buttons() == 0);

    // Forces: nothing rendered while disabled; the newest force once enabled.
    dev.write_force(Vector3::new(0.5, -1.0, 2.0)).unwrap();
    std::thread::sleep(Duration::from_millis(5));
    assert_eq!(fake.rendered(), [0.0; 3]);
    dev.set_forces_enabled(true).unwrap();
    eventually("force rendered", || fake.rendered() == [0.5, -1.0, 2.0]);
    assert!(fake.state().0);

    // A force limit trips: forces go off at once, the daemon hears a device error.
    fake.raise(0x0201);
    let err = first_error(|| dev.read(now(Instant::now())).map(drop));
    eventually("forces off", || {
        fake.rendered() == [0.0; 3] && !fake.state().0
    });
    assert!(matches!(err, HapticError::Device { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains("maximum force exceeded (Exceeded max force; HD error 0x0201, device code 7)"),
        "{msg}"
    );
    assert!(dev.read(now(Instant::now())).is_ok(), "reported once");
    // They stay off until the daemon enables them again.
    dev.write_force(Vector3::new(0.1, 0.0, 0.0)).unwrap();
    std::thread::sleep(Duration::from_millis(5));
    assert_eq!(fake.rendered(), [0.0; 3]);
    dev.set_forces_enabled(true).unwrap();
    eventually("re-enabled", || fake.rendered() == [0.1, 0.0, 0.0]);

    // A communication error is a lost device.
    fake.raise(0x0302);
    let err = first_error(|| dev.read(now(Instant::now())).map(drop));
    eventually("forces off", || !fake.state().0);
    assert!(matches!(err, HapticError::Lost { .. }), "{err:?}");

    // The servo loop stops: reported as lost after stall_ms.
    fake.pause(true);
    std::thread::sleep(Duration::from_millis(5));
    let _ = dev.read(now(Instant::now()));
    std::thread::sleep(Duration::from_millis(80));
    let err = dev.read(now(Instant::now())).unwrap_err();
    assert!(
        err.to_string().contains("servo loop has not ticked"),
        "{err}"
    );
    fake.pause(false);
    eventually("recovers", || dev.read(now(Instant::now())).is_ok());

    // Closing: zero force, force output off, scheduler stopped, device released.
    dev.set_forces_enabled(true).unwrap();
    dev.write_force(Vector3::new(1.0, 1.0, 1.0)).unwrap();
    eventually("force rendered", || fake.rendered() == [1.0; 3]);
    drop(dev);
    assert_eq!(fake.rendered(), [0.0; 3]);
    assert_eq!(fake.state(), (false, false, false, false));
}
