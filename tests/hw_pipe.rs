//! The `"pipe"` frame source end to end with a producer process (examples/pipe_producer,
//! built by `cargo test`): frames and their sequence numbers through a FIFO, a timeout
//! when the producer stops, a restart without reopening, resynchronisation after junk,
//! and raw frames from a file ending at EOF.
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use image::GrayImage;
use nanoforce::hw::frames::config::{PipeConfig, PipeFormat, PipePath};
use nanoforce::hw::frames::pipe::PipeSource;
use nanoforce::hw::frames::{FrameError, FrameSource};
use nanoforce::hw::Clock;

const W: u32 = 64;
const H: u32 = 48;

fn producer() -> PathBuf {
    // target/<profile>/deps/hw_pipe-<hash> -> target/<profile>/examples/pipe_producer
    let exe = std::env::current_exe().unwrap();
    let path = exe
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .join("examples/pipe_producer");
    assert!(
        path.exists(),
        "{} not built (cargo test builds examples)",
        path.display()
    );
    path
}

fn produce(path: &Path, args: &[&str]) -> Child {
    Command::new(producer())
        .arg("--path")
        .arg(path)
        .args([
            "--width",
            &W.to_string(),
            "--height",
            &H.to_string(),
            "--rate-hz",
            "200",
        ])
        .args(args)
        .spawn()
        .unwrap()
}

fn mkfifo(dir: &Path) -> PathBuf {
    let path = dir.join("frames.fifo");
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid path string.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    path
}

fn config(path: PathBuf, format: PipeFormat, timeout_ms: u64) -> PipeConfig {
    PipeConfig {
        path: PipePath::File(path),
        format,
        timeout_ms,
    }
}

/// The producer's pattern, pixel by pixel.
fn assert_frame(frame: &GrayImage, sequence: u64) {
    assert_eq!(frame.dimensions(), (W, H));
    for (x, y, p) in frame.enumerate_pixels() {
        let want = (u64::from(x) + 2 * u64::from(y) + sequence) as u8;
        assert_eq!(p.0[0], want, "pixel ({x}, {y}) of frame {sequence}");
    }
}

#[test]
fn fifo_frames_gaps_timeout_restart_and_resync() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = mkfifo(dir.path());
    let clock = Clock::start();
    let mut source =
        PipeSource::open(&config(fifo.clone(), PipeFormat::Header, 300), clock).unwrap();
    assert_eq!(source.name(), format!("pipe:{}", fifo.display()));
    // Every 4th sequence number is left out, as by a grabber that dropped frames.
    let mut child = produce(&fifo, &["--count", "9", "--skip-every", "4"]);
    let mut frame = GrayImage::new(0, 0);
    let mut sequences = Vec::new();
    for _ in 0..9 {
        let meta = source.next_frame(&mut frame).unwrap();
        assert_frame(&frame, meta.sequence);
        let age_s = clock.now_s() - meta.captured_s;
        assert!(
            (0.0..0.5).contains(&age_s),
            "capture time from the header: {age_s} s ago"
        );
        sequences.push(meta.sequence);
    }
    assert_eq!(sequences, [1, 2, 3, 5, 6, 7, 9, 10, 11]);
    assert!(child.wait().unwrap().success());

    // The producer is gone: a timeout, not an end of stream (the FIFO stays open).
    let started = Instant::now();
    let err = source.next_frame(&mut frame).unwrap_err();
    assert!(
        matches!(
            err,
            FrameError::Timeout {
                timeout_ms: 300,
                ..
            }
        ),
        "{err:?}"
    );
    let waited = started.elapsed();
    assert!(
        waited >= Duration::from_millis(290) && waited < Duration::from_millis(2000),
        "{waited:?}"
    );

    // It restarts after writing junk: the source skips to the next header.
    let mut child = produce(&fifo, &["--count", "2", "--garbage", "13"]);
    for want in [1, 2] {
        let meta = source.next_frame(&mut frame).unwrap();
        assert_eq!(meta.sequence, want);
        assert_frame(&frame, want);
    }
    assert!(child.wait().unwrap().success());
}

#[test]
fn raw_frames_from_a_file_end_at_eof() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("stream.raw");
    let status = produce(&file, &["--count", "3", "--raw"]).wait().unwrap();
    assert!(status.success());
    assert_eq!(
        std::fs::metadata(&file).unwrap().len(),
        3 * u64::from(W * H)
    );
    let format = PipeFormat::Raw {
        width: W,
        height: H,
    };
    let mut source = PipeSource::open(&config(file, format, 1000), Clock::start()).unwrap();
    let mut frame = GrayImage::new(W, H);
    for want in 1..=3 {
        let meta = source.next_frame(&mut frame).unwrap();
        assert_eq!(meta.sequence, want, "numbered on arrival");
        assert_frame(&frame, want);
    }
    let err = source.next_frame(&mut frame).unwrap_err();
    assert!(matches!(err, FrameError::EndOfStream { .. }), "{err:?}");
}

#[test]
fn a_missing_fifo_says_how_to_make_one() {
    let cfg = config(
        PathBuf::from("/nonexistent/frames.fifo"),
        PipeFormat::Header,
        100,
    );
    let err = PipeSource::open(&cfg, Clock::start())
        .err()
        .unwrap()
        .to_string();
    assert_eq!(
        err,
        "pipe:/nonexistent/frames.fifo: No such file or directory (os error 2) \
         (create the FIFO with `mkfifo /nonexistent/frames.fifo`)"
    );
}
