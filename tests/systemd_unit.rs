//! The systemd unit and the udev rules agree and stay narrow: no deprecated
//! udev-settle ordering, no device class that opens every HID or serial device, and the
//! haptic device's group and stable name in the rules are the ones the unit uses. The
//! Debian package (`[package.metadata.deb]`) installs the binary and the configuration
//! the unit runs, and its sysusers.d and tmpfiles.d entries make the unit's user, groups
//! and state directory.
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

/// `[package.metadata.deb]` of Cargo.toml: its assets as (source, destination) pairs.
fn package_assets() -> Vec<(String, String)> {
    let manifest: toml::Table = toml::from_str(&read("Cargo.toml")).expect("Cargo.toml parses");
    let deb = &manifest["package"]["metadata"]["deb"];
    deb["assets"]
        .as_array()
        .expect("[package.metadata.deb] assets")
        .iter()
        .map(|a| {
            let a = a.as_array().expect("an asset is [source, dest, mode]");
            (
                a[0].as_str().unwrap_or_default().to_string(),
                a[1].as_str().unwrap_or_default().to_string(),
            )
        })
        .collect()
}

#[test]
fn the_package_installs_what_the_unit_runs() {
    let unit = read("systemd/nanoforce.service");
    let exec = values(&unit, "ExecStart");
    let argv: Vec<&str> = exec
        .first()
        .expect("ExecStart=")
        .split_whitespace()
        .collect();
    let assets = package_assets();
    let dest_of = |source: &str| {
        assets
            .iter()
            .find(|(s, _)| s == source)
            .map(|(_, d)| d.clone())
            .unwrap_or_else(|| panic!("the package does not install {source}: {assets:?}"))
    };
    let bin_dir = dest_of("target/release/nanoforce");
    assert_eq!(
        argv[0],
        format!("/{bin_dir}nanoforce"),
        "ExecStart={exec:?}"
    );
    assert_eq!(argv.get(1), Some(&"run"));
    let config = argv
        .iter()
        .position(|a| *a == "--config")
        .and_then(|i| argv.get(i + 1))
        .expect("ExecStart names its --config");
    let conffile = dest_of("config/lab.example.toml");
    assert!(conffile.starts_with("etc/"), "a conffile lives in /etc");
    assert_eq!(*config, format!("/{conffile}"));
    let man = assets
        .iter()
        .find(|(_, d)| d.starts_with("usr/share/man/man1"))
        .expect("man pages");
    assert!(man.0.starts_with("target/dist/man/"), "{man:?}");
    assert!(assets
        .iter()
        .any(|(s, d)| s.starts_with("udev/") && d.starts_with("usr/lib/udev/rules.d")));
}

#[test]
fn sysusers_and_tmpfiles_make_the_units_user_groups_and_state_directory() {
    let unit = read("systemd/nanoforce.service");
    let rules = read("udev/99-nanoforce.rules");
    let sysusers = read("systemd/nanoforce.sysusers");
    let entries: Vec<Vec<&str>> = sysusers
        .lines()
        .filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().collect())
        .collect();
    let user = values(&unit, "User")[0];
    assert!(
        entries.iter().any(|e| e[0] == "u" && e[1] == user),
        "no `u {user}` in nanoforce.sysusers"
    );
    // `u` creates the user's own group; every other group the unit or the rules name
    // is created (or left as it is when the system has it) and has the user in it.
    let mut groups: Vec<&str> = values(&unit, "SupplementaryGroups")
        .iter()
        .flat_map(|v| v.split_whitespace())
        .collect();
    for line in rules.lines().filter(|l| !l.trim_start().starts_with('#')) {
        if let Some(rest) = line.split("GROUP=\"").nth(1) {
            groups.extend(rest.split('"').next());
        }
    }
    assert_eq!(values(&unit, "Group"), [user]);
    for group in groups.iter().filter(|g| **g != user) {
        assert!(
            entries.iter().any(|e| e[0] == "g" && e[1] == *group),
            "nanoforce.sysusers does not create group {group}"
        );
        assert!(
            entries
                .iter()
                .any(|e| e[0] == "m" && e[1] == user && e[2] == *group),
            "nanoforce.sysusers does not put {user} in {group}"
        );
    }
    let state = format!("/var/lib/{}", values(&unit, "StateDirectory")[0]);
    let mode = values(&unit, "StateDirectoryMode")[0];
    let tmpfiles = read("systemd/nanoforce.tmpfile");
    let line = tmpfiles
        .lines()
        .find(|l| l.starts_with("d "))
        .expect("a `d` line in nanoforce.tmpfile");
    assert_eq!(
        line.split_whitespace().take(5).collect::<Vec<_>>(),
        ["d", &state, mode, user, user],
        "the state directory as the unit makes it"
    );
}
