//! Building the fakes and running scenarios in child processes.
//!
//! A fake is a C file in `tests/fakes/`, compiled with the system `cc` into a temporary
//! directory once per test process. A scenario that needs the fake in place of a
//! link-time library (LD_LIBRARY_PATH) or in front of libc (LD_PRELOAD) runs in a child:
//! this test binary again, with `--ignored --exact <scenario>`, so the real nanoforce code
//! runs in a process whose dynamic linker sees the fake.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};

static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
static BUILT: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// The temporary directory holding the built fakes.
pub fn fake_dir() -> &'static Path {
    DIR.get_or_init(|| tempfile::tempdir().expect("temporary directory"))
        .path()
}

/// Compiles `tests/fakes/<source>` into `<fake_dir>/<output>` (once), with extra flags.
pub fn build(source: &str, output: &str, flags: &[&str]) -> PathBuf {
    let out = fake_dir().join(output);
    let mut built = BUILT.lock().unwrap();
    if built.iter().any(|b| b == output) {
        return out;
    }
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fakes")
        .join(source);
    let status = Command::new("cc")
        .args(["-shared", "-fPIC", "-O1", "-Wall", "-o"])
        .arg(&out)
        .arg(&src)
        .args(flags)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fakes"))
        .status()
        .expect("running cc (the fakes need a C compiler)");
    assert!(status.success(), "cc failed on {}", src.display());
    built.push(output.to_string());
    out
}

/// Runs the ignored test `scenario` of this binary in a child with `env`; asserts it
/// passed and returns its standard output.
pub fn run_child(scenario: &str, env: &[(&str, &str)]) -> String {
    let exe = std::env::current_exe().unwrap();
    let out = Command::new(exe)
        .args([
            "--ignored",
            "--exact",
            scenario,
            "--nocapture",
            "--test-threads=1",
        ])
        .envs(env.iter().copied())
        .env("NANOFORCE_FAKE_CHILD", "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stdout.contains("1 passed"),
        "child {scenario} failed:\n{stdout}\n{stderr}"
    );
    stdout
}

/// True inside a child started by [`run_child`] (scenarios refuse to run elsewhere).
pub fn in_child() -> bool {
    std::env::var_os("NANOFORCE_FAKE_CHILD").is_some()
}
