//! The daemon's log lines as the journal and a log file receive them: no escape codes
//! when standard error is not a terminal, and under systemd (`JOURNAL_STREAM` naming
//! standard error) a syslog priority first on every line and no timestamp.
use std::fs::File;
use std::os::unix::fs::MetadataExt;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

/// Runs the daemon on its simulated lab for a second with standard error to a file;
/// `journal` sets JOURNAL_STREAM to that file, as systemd does for its stream.
fn daemon_stderr(journal: bool) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stderr.log");
    let file = File::create(&path).unwrap();
    let meta = file.metadata().unwrap();
    let mut cmd = Command::new(BIN);
    cmd.args(["run", "--quiet", "--duration-s", "1", "--state-dir"])
        .arg(dir.path())
        .env("RUST_LOG", "info")
        .env_remove("JOURNAL_STREAM")
        .stderr(file);
    if journal {
        cmd.env("JOURNAL_STREAM", format!("{}:{}", meta.dev(), meta.ino()));
    }
    let status = cmd.status().unwrap();
    assert!(status.success(), "{status}");
    std::fs::read_to_string(&path).unwrap()
}

#[test]
fn a_log_file_gets_no_escape_codes() {
    let err = daemon_stderr(false);
    assert!(err.lines().count() >= 2, "{err}");
    assert!(!err.contains('\x1b'), "{err}");
    assert!(err.lines().all(|l| !l.starts_with('<')), "{err}");
}

#[test]
fn under_systemd_every_line_has_its_priority_and_no_time() {
    let err = daemon_stderr(true);
    assert!(err.lines().count() >= 2, "{err}");
    assert!(!err.contains('\x1b'), "{err}");
    for line in err.lines() {
        let b = line.as_bytes();
        assert!(
            b.len() > 4 && b[0] == b'<' && (b'0'..=b'7').contains(&b[1]) && b[2] == b'>',
            "no priority: {line}"
        );
        assert!(
            line[3..].starts_with("nanoforce"),
            "a time or level: {line}"
        );
    }
    assert!(err.lines().any(|l| l.starts_with("<6>")), "{err}");
}

#[test]
fn a_journal_stream_of_another_file_is_ignored() {
    // A child whose standard error was redirected inherits JOURNAL_STREAM: it must not
    // write priorities into its own file.
    let dir = tempfile::tempdir().unwrap();
    let err_path = dir.path().join("stderr.log");
    let other = File::create(dir.path().join("other"))
        .unwrap()
        .metadata()
        .unwrap();
    let status = Command::new(BIN)
        .args(["run", "--quiet", "--duration-s", "1", "--state-dir"])
        .arg(dir.path())
        .env("RUST_LOG", "info")
        .env("JOURNAL_STREAM", format!("{}:{}", other.dev(), other.ino()))
        .stderr(File::create(&err_path).unwrap())
        .status()
        .unwrap();
    assert!(status.success());
    let err = std::fs::read_to_string(&err_path).unwrap();
    assert!(err.lines().count() >= 2, "{err}");
    assert!(err.lines().all(|l| !l.starts_with('<')), "{err}");
}

#[test]
fn under_systemd_the_final_error_is_priority_3() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stderr.log");
    let file = File::create(&path).unwrap();
    let meta = file.metadata().unwrap();
    let status = Command::new(BIN)
        .args(["run", "--config"])
        .arg(dir.path().join("missing.toml"))
        .env("JOURNAL_STREAM", format!("{}:{}", meta.dev(), meta.ino()))
        .stderr(file)
        .status()
        .unwrap();
    assert!(!status.success());
    let err = std::fs::read_to_string(&path).unwrap();
    let last = err.lines().last().unwrap_or_default();
    assert!(last.starts_with("<3>nanoforce: error: "), "{err}");
    assert!(last.contains("missing.toml"), "{err}");
}
