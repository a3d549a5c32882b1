//! Devices as a lab meets them through the binary: `nanoforce probe-devices` reports
//! what works and why not (exit status non-zero on a failure), and `nanoforce run`
//! refuses to start, before READY and without motion, when a configured device cannot
//! be opened. Runs in every build: without the hardware features the reason is the
//! missing feature, with them the missing device. With `--features comedi` the daemon
//! also drives a fake comedi board for two seconds and leaves it at zero.
use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::process::{Command, Output};

#[cfg(feature = "comedi")]
#[allow(dead_code)]
#[path = "hw_fakes/support.rs"]
mod support;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

/// The built-in simulated lab with `[section]` replaced by `replacement`.
fn lab_config(dir: &Path, section: &str, replacement: &str) -> std::path::PathBuf {
    let sim =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim.toml"))
            .unwrap();
    let header = format!("[{section}]\nbackend = \"sim\"\n");
    assert!(sim.contains(&header), "config/sim.toml has {header:?}");
    let text = sim.replacen(&header, replacement, 1);
    let path = dir.join("lab.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn probe(config: Option<&Path>) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.args(["probe-devices", "--configured-only"]);
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    cmd.output().unwrap()
}

const MISSING_COMEDI: &str = "[daq]\nbackend = \"comedi\"\ndevice = \"/dev/comedi_missing9\"\n\
    [daq.x]\noutput = \"analog\"\nsubdevice = 1\nchannel = 0\nvolts_per_um_s = 0.1\n\
    [daq.y]\noutput = \"none\"\n\
    [daq.z]\noutput = \"analog\"\nsubdevice = 1\nchannel = 1\nvolts_per_um_s = 0.1\n";

fn missing_comedi_reason() -> &'static str {
    if cfg!(feature = "comedi") {
        "/dev/comedi_missing9: cannot open: No such file or directory"
    } else {
        "daq.backend = \"comedi\" needs a build with --features comedi"
    }
}

#[test]
fn probe_reports_the_simulated_lab() {
    let out = probe(None);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    for kind in ["frames", "daq", "haptic"] {
        let line = stdout
            .lines()
            .find(|l| l.contains(&format!("] {kind}")))
            .unwrap();
        assert!(
            line.starts_with("  [ ok ]") && line.contains("sim:"),
            "{line}"
        );
    }
}

#[test]
fn probe_names_what_cannot_be_opened_and_fails() {
    let dir = tempfile::tempdir().unwrap();
    let config = lab_config(dir.path(), "daq", MISSING_COMEDI);
    let out = probe(Some(&config));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    let daq = stdout.lines().find(|l| l.contains("] daq")).unwrap();
    assert!(
        daq.starts_with("  [FAIL]") && daq.contains(missing_comedi_reason()),
        "{daq}"
    );
    let frames = stdout.lines().find(|l| l.contains("] frames")).unwrap();
    assert!(frames.starts_with("  [ ok ]"), "{frames}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("1 configured device(s) cannot be used"));
}

#[test]
fn run_refuses_to_start_without_its_devices() {
    let dir = tempfile::tempdir().unwrap();
    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket.set_nonblocking(true).unwrap();
    for (section, replacement, reason) in [
        ("daq", MISSING_COMEDI, missing_comedi_reason().to_string()),
        (
            "haptic",
            "[haptic]\nbackend = \"openhaptics\"\nlibrary = \"/nonexistent/libHD.so\"\n",
            if cfg!(feature = "openhaptics") {
                "cannot load /nonexistent/libHD.so".into()
            } else {
                "haptic.backend = \"openhaptics\" needs a build with --features openhaptics".into()
            },
        ),
    ] {
        let config = lab_config(dir.path(), section, replacement);
        let out = Command::new(BIN)
            .args([
                "run",
                "--quiet",
                "--no-record",
                "--duration-s",
                "5",
                "--config",
            ])
            .arg(&config)
            .env("NOTIFY_SOCKET", &socket_path)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains("opening the lab's devices") && stderr.contains(&reason),
            "{stderr}"
        );
        let mut buf = [0u8; 256];
        assert!(
            socket.recv(&mut buf).is_err(),
            "nothing was sent to systemd, READY least of all"
        );
    }
}

/// The daemon at 1 kHz through the real comedi FFI path: the simulated operator moves,
/// the fake board sees the rate commands, and everything ends at zero.
#[cfg(feature = "comedi")]
#[test]
fn run_drives_a_fake_comedi_board_and_leaves_it_at_zero() {
    support::build(
        "fake_comedi.c",
        "libcomedi.so.0",
        &[
            "-Wl,-soname,libcomedi.so.0",
            "-Wl,--version-script=fake_comedi.map",
        ],
    );
    let dir = tempfile::tempdir().unwrap();
    let daq = MISSING_COMEDI.replace("/dev/comedi_missing9", "/fake/comedi0");
    let config = lab_config(dir.path(), "daq", &daq);
    let log = dir.path().join("comedi.log");
    let out = Command::new(BIN)
        .args([
            "run",
            "--quiet",
            "--no-record",
            "--duration-s",
            "2",
            "--config",
        ])
        .arg(&config)
        .env("LD_LIBRARY_PATH", support::fake_dir())
        .env("FAKE_COMEDI_LOG", &log)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&log).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "open /fake/comedi0");
    // The simulated operator approaches the sample: along stage z.
    let writes: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.starts_with("data_write 1 1 "))
        .collect();
    assert!(
        writes.len() > 5,
        "the z output changed as the operator moved: {writes:?}"
    );
    assert!(
        writes.len() < 1500,
        "written on change only, not every tick: {}",
        writes.len()
    );
    assert!(
        writes.iter().any(|w| !w.ends_with(" 2048")),
        "motion was commanded"
    );
    // The last commands on both axes (x and z) are 0 V (code 2048 of 4095 on +-10 V), then close.
    let n = lines.len();
    assert_eq!(
        lines[n - 3..],
        [
            "data_write 1 0 0 0 2048",
            "data_write 1 1 0 0 2048",
            "close"
        ]
    );
}

#[test]
fn the_lab_example_config_is_valid() {
    use nanoforce::hw::config::{DaqBackend, FramesBackend, HapticBackend};
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/lab.example.toml");
    let cfg = nanoforce::config::Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(cfg.devices.frames, FramesBackend::V4l2(_)));
    assert!(matches!(cfg.devices.haptic, HapticBackend::OpenHaptics(_)));
    let DaqBackend::Comedi(daq) = &cfg.devices.positioners[0].daq else {
        panic!("comedi expected")
    };
    assert_eq!(daq.axis_devices[2], Path::new("/dev/comedi0"));
    assert!(matches!(
        daq.axes[2],
        nanoforce::hw::daq::config::AxisOutput::StepDir(_)
    ));
}
