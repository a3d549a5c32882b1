//! The v4l2 backend against a fake capture device (an LD_PRELOAD shim compiled against
//! the kernel's videodev2.h, in a child process): the ioctl sequence of mmap streaming,
//! GREY with padded rows and YUYV, kernel timestamps, dropped frames as sequence gaps,
//! an unplugged device reported and reopened, a timeout, a format the device refuses,
//! and a missing device.
use std::path::PathBuf;

use image::GrayImage;
use nanoforce::hw::frames::config::{PixelFormat, V4l2Config};
use nanoforce::hw::frames::v4l2::V4l2Source;
use nanoforce::hw::frames::{FrameError, FrameSource};
use nanoforce::hw::Clock;

use super::support::{build, in_child, run_child};

#[test]
fn capture_through_a_fake_video_device() {
    let shim = build("fake_v4l2.c", "libfakev4l2.so", &["-ldl"]);
    let log = std::env::temp_dir().join(format!("fake-v4l2-{}.log", std::process::id()));
    let _ = std::fs::remove_file(&log);
    run_child(
        "v4l2::child_capture",
        &[
            ("LD_PRELOAD", shim.to_str().unwrap()),
            ("FAKE_V4L2_LOG", log.to_str().unwrap()),
            ("FAKE_V4L2_DROP", "3,4,8"),
            ("FAKE_V4L2_MISSING_OPENS", "2"),
        ],
    );
    let _ = std::fs::remove_file(&log);
}

fn config(pixel_format: PixelFormat, width: u32, height: u32, rate_hz: f64) -> V4l2Config {
    V4l2Config {
        device: PathBuf::from("/dev/fakevideo0"),
        pixel_format,
        width,
        height,
        rate_hz,
        buffers: 4,
        timeout_ms: 300,
    }
}

/// The fake's pattern for kernel sequence `raw`.
fn assert_pattern(frame: &GrayImage, raw: u64) {
    for (x, y, p) in frame.enumerate_pixels() {
        let want = (u64::from(x) + 2 * u64::from(y) + raw) as u8;
        assert_eq!(p.0[0], want, "pixel ({x}, {y}), kernel sequence {raw}");
    }
}

fn log_lines() -> Vec<String> {
    let path = std::env::var("FAKE_V4L2_LOG").unwrap();
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect()
}

#[test]
#[ignore = "run by capture_through_a_fake_video_device under the LD_PRELOAD shim"]
fn child_capture() {
    assert!(in_child());
    let clock = Clock::start();
    let mut frame = GrayImage::new(0, 0);

    // GREY 70x40 at 200 Hz; the device pads rows to 80 bytes and drops 3, 4 and 8.
    let mut source = V4l2Source::open(&config(PixelFormat::Grey, 70, 40, 200.0), clock).unwrap();
    assert_eq!(source.name(), "v4l2:/dev/fakevideo0 70x40 Grey");
    let mut sequences = Vec::new();
    let mut times = Vec::new();
    for _ in 0..10 {
        let meta = source.next_frame(&mut frame).unwrap();
        assert_eq!(frame.dimensions(), (70, 40));
        assert_pattern(&frame, meta.sequence - 1);
        let age_s = clock.now_s() - meta.captured_s;
        assert!(
            (0.0..0.1).contains(&age_s),
            "kernel timestamp on our clock: {age_s} s old"
        );
        sequences.push(meta.sequence);
        times.push(meta.captured_s);
    }
    assert_eq!(
        sequences,
        [1, 2, 3, 6, 7, 8, 10, 11, 12, 13],
        "gaps = dropped frames"
    );
    let mean_period_s = (times[9] - times[0]) / 9.0;
    assert!(
        (mean_period_s - 0.005).abs() < 1e-6,
        "200 Hz asked for: {mean_period_s}"
    );
    drop(source);
    let log = log_lines();
    assert_eq!(
        log[..11],
        [
            "open /dev/fakevideo0",
            "QUERYCAP",
            "S_FMT GREY 70x40 bpl 80",
            "S_PARM 1000/200000",
            "REQBUFS 4",
            "mmap 0",
            "mmap 1",
            "mmap 2",
            "mmap 3",
            "STREAMON",
            "DQBUF 0 seq 0",
        ]
    );
    assert_eq!(log[log.len() - 2..], ["STREAMOFF", "close"]);

    // YUYV: the luma bytes.
    let mut source = V4l2Source::open(&config(PixelFormat::Yuyv, 64, 32, 200.0), clock).unwrap();
    let meta = source.next_frame(&mut frame).unwrap();
    assert_eq!((frame.dimensions(), meta.sequence), ((64, 32), 1));
    assert_pattern(&frame, 0);

    // Unplugged after 3 more frames: reported, then reopened once it is back.
    let done = log_lines()
        .iter()
        .filter(|l| l.starts_with("DQBUF"))
        .count();
    std::env::set_var("FAKE_V4L2_VANISH_AT", (done + 3).to_string());
    let mut last = 0;
    for _ in 0..3 {
        last = source.next_frame(&mut frame).unwrap().sequence;
    }
    let err = source.next_frame(&mut frame).unwrap_err().to_string();
    assert!(
        err.contains("device lost") && err.contains("reopening"),
        "{err}"
    );
    for _ in 0..2 {
        let err = source.next_frame(&mut frame).unwrap_err().to_string();
        assert!(
            err.contains("reopening: cannot open: No such file or directory"),
            "{err}"
        );
    }
    let meta = source.next_frame(&mut frame).unwrap();
    assert!(
        meta.sequence > last,
        "sequence continues after a reopen: {} > {last}",
        meta.sequence
    );
    assert_pattern(&frame, 0);
    drop(source);

    // A frame rate too slow for the timeout: reported as a timeout.
    let mut source = V4l2Source::open(&config(PixelFormat::Grey, 32, 16, 2.0), clock).unwrap();
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
    drop(source);

    // A format the device does not offer, and a device that is not there.
    let err = V4l2Source::open(&config(PixelFormat::Mjpeg, 32, 16, 30.0), clock)
        .err()
        .unwrap();
    assert!(
        err.to_string()
            .contains("does not offer Mjpeg frames (it chose \"GREY\")"),
        "{err}"
    );
    let mut missing = config(PixelFormat::Grey, 32, 16, 30.0);
    missing.device = PathBuf::from("/dev/nonexistent-video9");
    let err = V4l2Source::open(&missing, clock).err().unwrap().to_string();
    assert_eq!(
        err,
        "v4l2:/dev/nonexistent-video9 32x16 Grey: cannot open: No such file or directory (os error 2)"
    );
}
