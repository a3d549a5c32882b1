//! A tiny producer for nanoforce's `"pipe"` frame source (docs/hardware.md): writes
//! synthetic 8-bit frames, each behind the 32-byte NFRM header, into a FIFO or to
//! standard output. A capture program for the NI PCI-1410 does the same with real
//! frames: header (size, its frame counter, CLOCK_MONOTONIC capture time), then pixels.
//!
//! ```text
//! mkfifo /run/nanoforce/frames.fifo
//! cargo run --example pipe_producer -- --path /run/nanoforce/frames.fifo --rate-hz 30
//! ```
//!
//! Options: --path FIFO|- (default -), --width 640, --height 480, --rate-hz 30,
//! --count N (default: forever), --skip-every N (leave out every N-th sequence number,
//! as a grabber that drops frames), --garbage N (N junk bytes first), --raw (no headers).
//! Pixel (x, y) of frame `sequence` is `(x + 2 y + sequence) mod 256`.
use std::io::Write;
use std::time::{Duration, Instant};

use nanoforce::hw::clock::monotonic_ns;
use nanoforce::hw::frames::pipe::FrameHeader;

fn main() -> std::io::Result<()> {
    let mut path = "-".to_string();
    let (mut width, mut height, mut rate_hz) = (640u32, 480u32, 30.0f64);
    let (mut count, mut skip_every, mut garbage, mut raw) = (u64::MAX, 0u64, 0usize, false);
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        let bad =
            |what: &str| std::io::Error::new(std::io::ErrorKind::InvalidInput, what.to_string());
        match arg.as_str() {
            "--path" => path = value(),
            "--width" => width = value().parse().map_err(|_| bad("--width"))?,
            "--height" => height = value().parse().map_err(|_| bad("--height"))?,
            "--rate-hz" => rate_hz = value().parse().map_err(|_| bad("--rate-hz"))?,
            "--count" => count = value().parse().map_err(|_| bad("--count"))?,
            "--skip-every" => skip_every = value().parse().map_err(|_| bad("--skip-every"))?,
            "--garbage" => garbage = value().parse().map_err(|_| bad("--garbage"))?,
            "--raw" => raw = true,
            other => return Err(bad(&format!("unknown option {other}"))),
        }
    }
    let mut out: Box<dyn Write> = if path == "-" {
        Box::new(std::io::stdout().lock())
    } else {
        Box::new(
            std::fs::OpenOptions::new()
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)?,
        )
    };
    out.write_all(&vec![0x5a; garbage])?;
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let start = Instant::now();
    let mut pixels = vec![0u8; (width * height) as usize];
    let mut sequence = 0u64;
    for n in 0..count {
        sequence += 1;
        if skip_every > 0 && sequence.is_multiple_of(skip_every) {
            sequence += 1;
        }
        let capture_ns = monotonic_ns();
        for (i, p) in pixels.iter_mut().enumerate() {
            let (x, y) = (i as u64 % u64::from(width), i as u64 / u64::from(width));
            *p = (x + 2 * y + sequence) as u8;
        }
        if !raw {
            out.write_all(
                &FrameHeader {
                    width,
                    height,
                    sequence,
                    capture_ns,
                }
                .encode(),
            )?;
        }
        out.write_all(&pixels)?;
        out.flush()?;
        if let Some(wait) = (start + period * (n as u32 + 1)).checked_duration_since(Instant::now())
        {
            std::thread::sleep(wait);
        }
    }
    Ok(())
}
