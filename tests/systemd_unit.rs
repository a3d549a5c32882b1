//! The systemd unit and the udev rules agree and stay narrow: no deprecated
//! udev-settle ordering, no device class that opens every HID or serial device, and the
//! haptic device's group and stable name in the rules are the ones the unit uses.
use std::path::Path;

fn read(path: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path))
        .unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The values of `key=` lines (comments skipped).
fn values<'a>(text: &'a str, key: &str) -> Vec<&'a str> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.strip_prefix(key)?.strip_prefix('='))
        .map(str::trim)
        .collect()
}

#[test]
fn unit_has_no_udev_settle_and_no_class_wide_hid_or_serial_access() {
    let unit = read("systemd/nanoforce.service");
    assert!(
        !unit.contains("systemd-udev-settle"),
        "systemd-udev-settle.service is deprecated"
    );
    let allowed = values(&unit, "DeviceAllow");
    assert!(!allowed.is_empty());
    for entry in &allowed {
        let device = entry.split_whitespace().next().unwrap_or("");
        assert!(
            !["char-hidraw", "char-ttyACM", "char-tty", "char-usb"].contains(&device),
            "DeviceAllow={entry} opens a whole class of devices"
        );
    }
    for node in ["/dev/nanoforce/haptic", "/dev/nanoforce/haptic-serial"] {
        assert!(
            allowed
                .iter()
                .any(|e| e.split_whitespace().next() == Some(node)),
            "DeviceAllow={node} rw: {allowed:?}"
        );
    }
    assert!(values(&unit, "DevicePolicy").contains(&"closed"));
}

#[test]
fn udev_rules_give_the_unit_its_groups_and_names() {
    let unit = read("systemd/nanoforce.service");
    let rules = read("udev/99-nanoforce.rules");
    let groups: Vec<&str> = values(&unit, "SupplementaryGroups")
        .iter()
        .flat_map(|v| v.split_whitespace())
        .collect();
    assert!(groups.contains(&"nanoforce-haptic"), "{groups:?}");
    assert!(
        !groups.contains(&"plugdev"),
        "plugdev is every user's removable device"
    );
    let rule_lines: Vec<&str> = rules
        .lines()
        .filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        .collect();
    for group in &groups {
        assert!(
            rule_lines
                .iter()
                .any(|l| l.contains(&format!("GROUP=\"{group}\""))),
            "no udev rule gives group {group}"
        );
    }
    for (kernel, link) in [
        ("hidraw", "nanoforce/haptic\""),
        ("ttyACM", "nanoforce/haptic-serial\""),
    ] {
        let rule = rule_lines
            .iter()
            .find(|l| l.contains(&format!("KERNEL==\"{kernel}")))
            .unwrap_or_else(|| panic!("no {kernel} rule"));
        assert!(
            rule.contains("ATTRS{idVendor}==")
                && rule.contains("GROUP=\"nanoforce-haptic\"")
                && rule.contains(&format!("SYMLINK+=\"{link}")),
            "the {kernel} rule matches the device and names it: {rule}"
        );
    }
}
