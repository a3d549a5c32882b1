//! The hid backend against a fake libhidapi-hidraw (LD_LIBRARY_PATH, child process)
//! replaying input reports in the Logitech Extreme 3D Pro's layout: a joystick gives
//! position only, and the switch button when it has one; a HID haptic device gets force
//! output reports, only when they change and zero when disabled or closed; an unplugged
//! device is lost.
use nalgebra::Vector3;
use nanoforce::hw::haptic::config::{HidAxis, HidConfig, HidForce};
use nanoforce::hw::haptic::hid::HidHaptic;
use nanoforce::hw::haptic::{HapticDevice, HapticError, SWITCH_BUTTON};

use super::support::{build, fake_dir, in_child, run_child};

#[test]
fn hid_devices_through_a_fake_hidapi() {
    build(
        "fake_hidapi.c",
        "libhidapi-hidraw.so.0",
        &["-Wl,-soname,libhidapi-hidraw.so.0"],
    );
    let dir = fake_dir().display().to_string();
    run_child(
        "hid::child_hid",
        &[
            ("LD_LIBRARY_PATH", &dir),
            ("FAKE_HID_VID", "046d"),
            ("FAKE_HID_PID", "c215"),
        ],
    );
}

fn config(force: Option<HidForce>) -> HidConfig {
    let axis = |bit, bits, max, invert| HidAxis {
        bit,
        bits,
        signed: false,
        min: 0,
        max,
        travel_mm: 60.0,
        invert,
    };
    HidConfig {
        vendor_id: 0x046d,
        product_id: 0xc215,
        report_id: None,
        report_length: 7,
        axes: [
            axis(0, 10, 1023, false),
            axis(10, 10, 1023, true),
            axis(24, 8, 255, false),
        ],
        switch_button_bit: None,
        force,
    }
}

struct Files {
    dir: tempfile::TempDir,
}

impl Files {
    fn reports(&self, lines: &[&str]) {
        let path = self.dir.path().join("reports.hex");
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        std::env::set_var("FAKE_HID_REPORTS", &path);
    }
    fn log(&self) -> Vec<String> {
        let text = std::fs::read_to_string(self.dir.path().join("hid.log")).unwrap_or_default();
        let _ = std::fs::remove_file(self.dir.path().join("hid.log"));
        text.lines().map(str::to_string).collect()
    }
}

const CENTRE: &str = "00 02 88 80 00 00 00";
/// Button 3 held (byte 4 holds buttons 1 to 8).
const CORNER: &str = "ff 03 80 ff 04 00 00";
/// The thumb button (2, bit 33) held.
const THUMB: &str = "00 02 88 80 02 00 00";

#[test]
#[ignore = "run by hid_devices_through_a_fake_hidapi with the fake hidapi"]
fn child_hid() {
    assert!(in_child());
    let files = Files {
        dir: tempfile::tempdir().unwrap(),
    };
    std::env::set_var("FAKE_HID_LOG", files.dir.path().join("hid.log"));

    // A joystick: position from the reports, no force output at all.
    files.reports(&[CENTRE, "-", CORNER]);
    let mut stick = HidHaptic::open(&config(None)).unwrap();
    assert_eq!(stick.name(), "hid:046d:c215");
    assert!(!stick.has_force_feedback());
    let centre = Vector3::new(30.0 / 1023.0, -30.0 / 1023.0, 30.0 / 255.0);
    let first = stick.read(0.000).unwrap().position_mm;
    assert!(
        (first - centre).norm() < 1e-12,
        "first report read at open: {first}"
    );
    let s = stick.read(0.001).unwrap();
    assert_eq!(s.position_mm, Vector3::new(30.0, 30.0, 30.0));
    assert!(s.velocity_mm_s.x > 0.0, "moving: {}", s.velocity_mm_s);
    assert_eq!(s.buttons, 0, "no switch button configured");
    // Silent afterwards: still there, and still.
    let s = stick.read(0.5).unwrap();
    assert_eq!(s.position_mm, Vector3::new(30.0, 30.0, 30.0));
    assert!(s.velocity_mm_s.norm() < 1e-3, "{}", s.velocity_mm_s);
    stick.set_forces_enabled(true).unwrap();
    stick.write_force(Vector3::new(1.0, 0.0, 0.0)).unwrap();
    // Unplugged: lost.
    std::env::set_var("FAKE_HID_UNPLUG", "1");
    let err = stick.read(0.6).unwrap_err();
    assert!(matches!(err, HapticError::Lost { .. }), "{err:?}");
    assert_eq!(
        err.to_string(),
        "hid:046d:c215: device lost: hid_read_timeout failed: Input/output error (device unplugged)"
    );
    drop(stick);
    std::env::remove_var("FAKE_HID_UNPLUG");
    assert_eq!(
        files.log(),
        ["open 046d:c215", "close"],
        "a joystick is never written to"
    );

    // The switch button at bit 33: held, another button alone, held again, released;
    // silent reads keep the newest report's buttons.
    files.reports(&[THUMB, "-", CORNER, "-", THUMB, "-", "-", CENTRE]);
    let mut switching = config(None);
    switching.switch_button_bit = Some(33);
    let mut stick = HidHaptic::open(&switching).unwrap();
    let mut buttons = |t| stick.read(t).unwrap().buttons;
    assert_eq!(buttons(0.000), SWITCH_BUTTON, "held at open");
    assert_eq!(buttons(0.001), 0, "button 3 is not the switch button");
    assert_eq!(buttons(0.002), SWITCH_BUTTON);
    assert_eq!(buttons(0.003), SWITCH_BUTTON, "silent: still held");
    assert_eq!(buttons(0.004), 0, "released");
    drop(stick);
    assert_eq!(files.log(), ["open 046d:c215", "close"]);

    // A HID haptic device: force output reports, zero at open, while disabled and at close.
    files.reports(&[CENTRE]);
    let force = HidForce {
        report_id: 2,
        report_length: 8,
        bytes: [1, 3, 5],
        full_scale_n: 4.0,
    };
    let mut dev = HidHaptic::open(&config(Some(force))).unwrap();
    assert!(dev.has_force_feedback());
    dev.write_force(Vector3::new(2.0, -4.0, 9.0)).unwrap();
    dev.set_forces_enabled(true).unwrap();
    dev.write_force(Vector3::new(2.0, -4.0, 9.0)).unwrap();
    dev.write_force(Vector3::new(2.0, -4.0, 9.0)).unwrap();
    dev.set_forces_enabled(false).unwrap();
    drop(dev);
    assert_eq!(
        files.log(),
        [
            "open 046d:c215",
            "write 02 00 00 00 00 00 00 00",
            "write 02 00 40 01 80 ff 7f 00",
            "write 02 00 00 00 00 00 00 00",
            "write 02 00 00 00 00 00 00 00",
            "close",
        ]
    );

    // Not plugged in (other ids): a clear open error.
    let mut other = config(None);
    other.product_id = 0xc216;
    let err = HidHaptic::open(&other).err().unwrap().to_string();
    assert_eq!(
        err,
        "hid:046d:c216: cannot open: hid_open failed: No HID device with the requested vendor and product id"
    );
}
