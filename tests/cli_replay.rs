//! `nanoforce replay` on recorded sessions: the CSV contract, determinism, frame
//! formats (PNG, 16-bit TIFF, PGM), corrupt files and overlays.
use std::path::{Path, PathBuf};
use std::process::Command;

use image::{GrayImage, ImageBuffer, Luma};

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/samples")
        .join(name)
}

fn replay(frames: &Path, config: &Path, csv: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .arg("replay")
        .arg(frames)
        .arg("--config")
        .arg(config)
        .arg("--csv")
        .arg(csv)
        .args(extra)
        .output()
        .unwrap()
}

/// A copy of a sample session's config and reference, with `n` frames in `frames/`.
fn session_copy(name: &str, n: usize) -> (tempfile::TempDir, PathBuf, Vec<GrayImage>) {
    let dir = tempfile::tempdir().unwrap();
    let src = sample(name);
    std::fs::copy(src.join("probe.toml"), dir.path().join("probe.toml")).unwrap();
    std::fs::copy(src.join("reference.png"), dir.path().join("reference.png")).unwrap();
    let frames = (0..n)
        .map(|i| {
            image::open(src.join(format!("frames/frame_{i:05}.png")))
                .unwrap()
                .into_luma8()
        })
        .collect();
    (dir, src, frames)
}

#[test]
fn csv_contract_and_byte_identical_reruns() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
    let s = sample("mixed");
    for csv in [&a, &b] {
        let out = replay(&s.join("frames"), &s.join("probe.toml"), csv, &[]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("replayed 30 frames:") && err.contains("ms per frame"),
            "{err}"
        );
    }
    let text = std::fs::read_to_string(&a).unwrap();
    assert_eq!(text, std::fs::read_to_string(&b).unwrap(), "deterministic");
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    assert!(
        header.starts_with("frame,detected,angle_deg,force_nN,tip_x,tip_y,"),
        "{header}"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 30);
    assert_eq!(rows[0][0], "frame_00000.png");
    for row in &rows {
        if row[1] == "1" {
            let angle: f64 = row[2].parse().unwrap();
            let force: f64 = row[3].parse().unwrap();
            assert_eq!(
                angle.signum(),
                force.signum(),
                "force has the angle's sign: {row:?}"
            );
        } else {
            assert!(
                row[2..6].iter().all(|v| v.is_empty()),
                "no values when not detected"
            );
        }
    }
}

#[test]
fn corrupt_frames_are_reported_and_skipped() {
    let (dir, _src, frames) = session_copy("mixed", 3);
    let frames_dir = dir.path().join("frames");
    std::fs::create_dir(&frames_dir).unwrap();
    frames[0].save(frames_dir.join("frame_00000.png")).unwrap();
    std::fs::write(
        frames_dir.join("frame_00001.png"),
        b"\x89PNG\r\n\x1a\ntruncated",
    )
    .unwrap();
    std::fs::write(frames_dir.join("frame_00002.tif"), b"").unwrap();
    frames[2].save(frames_dir.join("frame_00003.png")).unwrap();
    let csv = dir.path().join("out.csv");
    let out = replay(&frames_dir, &dir.path().join("probe.toml"), &csv, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("frame_00001.png: cannot decode"), "{err}");
    assert!(err.contains("2 unreadable"), "{err}");
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = text.lines().skip(1).collect();
    assert_eq!(rows.len(), 4);
    assert!(rows[1].starts_with("frame_00001.png,0,,,,,") && rows[1].ends_with("unreadable"));
    assert!(rows[2].starts_with("frame_00002.tif,0,"));
    assert!(rows[0].starts_with("frame_00000.png,1,") && rows[3].starts_with("frame_00003.png,1,"));
}

/// Writes a frame in one file format.
type SaveFn = fn(&GrayImage, &Path);

#[test]
fn tiff16_and_pgm_frames_track_like_png() {
    let (dir, _src, frames) = session_copy("mixed", 4);
    let formats: [(&str, SaveFn); 3] = [
        ("png", |img, p| img.save(p).unwrap()),
        ("pgm", |img, p| img.save(p).unwrap()),
        ("tif", |img, p| {
            let wide: ImageBuffer<Luma<u16>, Vec<u16>> =
                ImageBuffer::from_fn(img.width(), img.height(), |x, y| {
                    Luma([u16::from(img.get_pixel(x, y)[0]) * 257])
                });
            wide.save(p).unwrap()
        }),
    ];
    let mut outputs = Vec::new();
    for (ext, save) in formats {
        let frames_dir = dir.path().join(ext);
        std::fs::create_dir(&frames_dir).unwrap();
        for (i, f) in frames.iter().enumerate() {
            save(f, &frames_dir.join(format!("frame_{i:05}.{ext}")));
        }
        let csv = dir.path().join(format!("{ext}.csv"));
        let out = replay(
            &frames_dir,
            &dir.path().join("probe.toml"),
            &csv,
            &["--no-coherence"],
        );
        assert!(
            out.status.success(),
            "{ext}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // Same rows apart from the file name's extension.
        let text = std::fs::read_to_string(&csv)
            .unwrap()
            .replace(&format!(".{ext},"), ".X,");
        outputs.push(text);
    }
    assert_eq!(outputs[0], outputs[1], "PGM");
    assert_eq!(outputs[0], outputs[2], "16-bit TIFF");
    assert_eq!(
        outputs[0]
            .lines()
            .skip(1)
            .filter(|l| l.contains(".X,1,"))
            .count(),
        4
    );
}

#[test]
fn overlays_are_written_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let s = sample("sequence");
    let overlays = dir.path().join("overlays");
    let out = replay(
        &s.join("frames"),
        &s.join("probe.toml"),
        &dir.path().join("o.csv"),
        &["--overlay", overlays.to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Frame 1 is at 2000x: all three edges in view (frame 0, at 8000x, shows the apex only).
    let overlay = image::open(overlays.join("frame_00001.png"))
        .unwrap()
        .into_rgb8();
    // The edges are drawn in pure-ish red, blue and green somewhere on the frame.
    let has = |want: fn(&image::Rgb<u8>) -> bool| overlay.pixels().any(want);
    assert!(has(|p| p[0] > 200 && p[1] < 100 && p[2] < 100), "red edge");
    assert!(has(|p| p[2] > 200 && p[0] < 100 && p[1] < 150), "blue edge");
    assert!(
        has(|p| p[1] > 200 && p[0] < 100 && p[2] < 100),
        "green edge"
    );
    assert_eq!(std::fs::read_dir(&overlays).unwrap().count(), 60);
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("probe.toml");
    std::fs::write(
        &config,
        "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n",
    )
    .unwrap();
    let s = sample("mixed");
    let out = replay(&s.join("frames"), &config, &dir.path().join("x.csv"), &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no [tracker.calibration]"));
    let out = replay(
        dir.path(),
        &s.join("probe.toml"),
        &dir.path().join("x.csv"),
        &[],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no frames"));
    std::fs::write(
        &config,
        std::fs::read_to_string(s.join("probe.toml"))
            .unwrap()
            .replace("reference.png", "missing.png"),
    )
    .unwrap();
    let out = replay(&s.join("frames"), &config, &dir.path().join("x.csv"), &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("missing.png") && err.contains("reference_image"),
        "{err}"
    );
}
