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

/// `nanoforce run` of `config` (state under `dir`), which must refuse it: its message.
fn refused_run(dir: &Path, config: &Path) -> String {
    let run = Command::new(BIN)
        .args(["run", "--duration-s", "1", "--config"])
        .arg(config)
        .arg("--state-dir")
        .arg(dir.join("state"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr).to_string();
    assert!(!run.status.success(), "{err}");
    err
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

/// A results CSV as rows of named cells.
fn read_rows(csv: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            let cells = l.split(',').map(String::from);
            header.iter().cloned().zip(cells).collect()
        })
        .collect()
}

/// `text` with every clicked pixel of `[tracker.calibration]` given from the corner:
/// the same pixels, plus half a pixel.
fn clicks_from_the_corner(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let key = ["red", "blue", "green"]
            .into_iter()
            .find(|k| line.starts_with(&format!("{k} = [[")));
        match key {
            Some(key) => {
                let values: Vec<f64> = line[key.len() + 3..]
                    .split(['[', ']', ','])
                    .filter_map(|v| v.trim().parse().ok())
                    .collect();
                let points: Vec<String> = values
                    .chunks(2)
                    .map(|p| format!("[{}, {}]", p[0] + 0.5, p[1] + 0.5))
                    .collect();
                out += &format!("{key} = [{}]\n", points.join(", "));
            }
            None => out += &format!("{line}\n"),
        }
    }
    out
}

#[test]
fn pixel_origin_and_edge_bias_move_only_the_pixels() {
    let (dir, _, frames) = session_copy("sequence", 12);
    std::fs::create_dir(dir.path().join("frames")).unwrap();
    for (i, f) in frames.iter().enumerate() {
        f.save(dir.path().join(format!("frames/frame_{i:05}.png")))
            .unwrap();
    }
    let plain = dir.path().join("probe.toml");
    let text = std::fs::read_to_string(&plain).unwrap();
    assert!(text.contains("window_deg = 20.0\n"));
    let keyed = dir.path().join("corner.toml");
    std::fs::write(
        &keyed,
        clicks_from_the_corner(&text.replace(
            "window_deg = 20.0\n",
            "window_deg = 20.0\npixel_origin = \"corner\"\nedge_bias_px = 0.3\n",
        )),
    )
    .unwrap();
    let frames_dir = dir.path().join("frames");
    let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
    for (config, csv) in [(&plain, &a), (&keyed, &b)] {
        let out = replay(&frames_dir, config, csv, &[]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let (a, b) = (read_rows(&a), read_rows(&b));
    assert_eq!(a.len(), 12);
    let num = |r: &std::collections::HashMap<String, String>, k: &str| -> f64 {
        r[k].parse().unwrap_or_else(|_| panic!("{k}: {:?}", r[k]))
    };
    for (a, b) in a.iter().zip(&b) {
        assert_eq!(a["detected"], "1", "{a:?}");
        for k in [
            "angle_deg",
            "force_nN",
            "confidence",
            "angle_sigma_deg",
            "scale",
        ] {
            assert_eq!(a[k], b[k], "{k}: the same tracking");
        }
        // Edge ends: the same points, counted from the corner.
        for k in a.keys().filter(|k| k.contains("_x") || k.contains("_y")) {
            if k.starts_with("tip") || a[k].is_empty() {
                continue;
            }
            assert!(
                (num(b, k) - num(a, k) - 0.5).abs() < 0.006,
                "{k}: {a:?} {b:?}"
            );
        }
        // The apex: where the imaged faces meet (centre), or 0.3 px inside both
        // (corner, less its half pixel).
        let tip = |r, d: f64| [num(r, "tip_x") - d, num(r, "tip_y") - d];
        let depth = |p: [f64; 2], face: &str| {
            let (x0, y0) = (num(a, &format!("{face}_x0")), num(a, &format!("{face}_y0")));
            let (x1, y1) = (num(a, &format!("{face}_x1")), num(a, &format!("{face}_y1")));
            let (dx, dy) = (x1 - x0, y1 - y0);
            ((p[0] - x0) * dy - (p[1] - y0) * dx).abs() / dx.hypot(dy)
        };
        for face in ["blue", "green"] {
            let imaged = depth(tip(a, 0.0), face);
            let true_apex = depth(tip(b, 0.5), face);
            assert!(imaged < 0.01, "{face}: {imaged} {a:?}");
            assert!((true_apex - 0.3).abs() < 0.01, "{face}: {true_apex} {b:?}");
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
    // Unreadable, frame 2 of the folder; no time, nothing published, not felt.
    assert!(
        rows[1].starts_with("frame_00001.png,0,,,,,") && rows[1].ends_with("unreadable,2,,,,,,,0")
    );
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

/// The bytes of every file in `dir`, by name.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            let bytes = std::fs::read(e.path()).unwrap_or_default();
            (e.file_name().to_string_lossy().to_string(), bytes)
        })
        .collect()
}

#[test]
fn outputs_that_would_overwrite_inputs_are_refused_before_writing() {
    let (dir, _src, frames) = session_copy("mixed", 2);
    let root = dir.path();
    let frames_dir = root.join("frames");
    std::fs::create_dir(&frames_dir).unwrap();
    frames[0].save(frames_dir.join("x.png")).unwrap();
    frames[1].save(frames_dir.join("reference.png")).unwrap();
    let config = root.join("probe.toml");
    let before = (snapshot(root), snapshot(&frames_dir));
    let csv = root.join("out.csv");
    let refused = |extra: &[&str], csv: &Path, want: &str| {
        let out = replay(&frames_dir, &config, csv, extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{extra:?} accepted: {err}");
        assert!(err.contains(want), "{extra:?}: {err}");
    };
    let overlay = |dir: &Path| ["--overlay".to_string(), dir.display().to_string()];
    // The frames folder itself, spelled plainly, with `..` and through a symbolic link.
    for spelling in [
        frames_dir.clone(),
        frames_dir.join("../frames"),
        root.join("./frames/"),
    ] {
        let args = overlay(&spelling);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused(&args, &csv, "is the frames folder");
    }
    let link = root.join("link");
    std::os::unix::fs::symlink(&frames_dir, &link).unwrap();
    let args = overlay(&link);
    refused(&[&args[0], &args[1]], &csv, "is the frames folder");
    // The session folder: frames/reference.png's overlay would be the reference image.
    let args = overlay(root);
    refused(
        &[&args[0], &args[1]],
        &csv,
        "would overwrite the reference image",
    );
    // The CSV onto a frame or the configuration.
    refused(&[], &frames_dir.join("x.png"), "is the frame");
    refused(&[], &link.join("x.png"), "is the frame");
    refused(&[], &config, "is the configuration");
    std::fs::remove_file(&link).unwrap();
    assert_eq!(
        (snapshot(root), snapshot(&frames_dir)),
        before,
        "nothing written"
    );
}

#[test]
fn frames_differing_only_in_extension_get_distinct_overlays() {
    let (dir, _src, frames) = session_copy("mixed", 2);
    let frames_dir = dir.path().join("frames");
    std::fs::create_dir(&frames_dir).unwrap();
    frames[0].save(frames_dir.join("x.png")).unwrap();
    frames[1].save(frames_dir.join("x.tif")).unwrap();
    frames[1].save(frames_dir.join("y.pgm")).unwrap();
    let overlays = dir.path().join("overlays");
    let config = dir.path().join("probe.toml");
    let csv = dir.path().join("out.csv");
    let args = ["--overlay", overlays.to_str().unwrap()];
    let out = replay(&frames_dir, &config, &csv, &args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let names: Vec<String> = snapshot(&overlays).into_keys().collect();
    assert_eq!(names, ["x.png", "x.tif.png", "y.pgm.png"]);
    let a = image::open(overlays.join("x.png")).unwrap().into_rgb8();
    let b = image::open(overlays.join("x.tif.png")).unwrap().into_rgb8();
    assert_ne!(a, b, "each overlay drawn on its own frame");
    // A PNG frame named like another frame's overlay: refused, nothing written.
    frames[0].save(frames_dir.join("x.tif.png")).unwrap();
    std::fs::remove_dir_all(&overlays).unwrap();
    std::fs::remove_file(&csv).unwrap();
    let out = replay(&frames_dir, &config, &csv, &args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("would both write the overlay x.tif.png"),
        "{err}"
    );
    assert!(!overlays.exists() && !csv.exists(), "nothing written");
}

#[test]
fn a_probe_without_a_cantilever_is_tracked_for_its_pose_only() {
    // The public sample's probe without its [cantilever]: a needle or a gripper jaw as
    // far as the configuration knows. Replay reports its pose and no force; `run`
    // refuses it, since it renders a force.
    let (dir, src, _) = session_copy("mixed", 0);
    let text = std::fs::read_to_string(dir.path().join("probe.toml")).unwrap();
    let start = text.find("[cantilever]").unwrap();
    let end = start + text[start..].find("\n[").unwrap() + 1;
    let no_force = dir.path().join("needle.toml");
    std::fs::write(&no_force, format!("{}{}", &text[..start], &text[end..])).unwrap();
    let csv = dir.path().join("pose.csv");
    let out = replay(&src.join("frames"), &no_force, &csv, &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows = read_rows(&csv);
    assert_eq!(rows.len(), 30);
    let detected: Vec<_> = rows.iter().filter(|r| r["detected"] == "1").collect();
    assert!(detected.len() >= 25, "{} detected", detected.len());
    for r in &detected {
        assert!(r["angle_deg"].parse::<f64>().is_ok() && r["tip_x"].parse::<f64>().is_ok());
        assert_eq!(
            (r["force_nN"].as_str(), r["felt"].as_str()),
            ("", "0"),
            "{r:?}"
        );
    }
    let err = refused_run(dir.path(), &no_force);
    assert!(
        err.contains("no [cantilever] section") && err.contains("can be calibrated and replayed"),
        "{err}"
    );
}

#[test]
fn several_probes_get_one_results_file_each() {
    // Two probes facing each other in one view, rendered with their truth: replay
    // writes out.<name>.csv per probe in the one format, each scoring against its own
    // truth; the overlays draw both.
    let dir = tempfile::tempdir().unwrap();
    let session = nanoforce::scene::Session::several(21, 2, 12, 640, 480);
    session
        .write(dir.path(), nanoforce::scene::FrameFormat::Png)
        .unwrap();
    let config = dir.path().join("probe.toml");
    let csv = dir.path().join("out.csv");
    let overlays = dir.path().join("overlays");
    let out = replay(
        &dir.path().join("frames"),
        &config,
        &csv,
        &["--overlay", overlays.to_str().unwrap()],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("probe1 ") && err.contains("probe2 "), "{err}");
    assert!(!csv.exists(), "one file per probe, none for the set");
    for name in ["probe1", "probe2"] {
        let results = dir.path().join(format!("out.{name}.csv"));
        let header = std::fs::read_to_string(&results).unwrap();
        assert!(header.starts_with(&nanoforce::session::results::header()));
        let truth =
            nanoforce::session::score::read_truth(&dir.path().join(format!("truth.{name}.csv")))
                .unwrap();
        let rows = nanoforce::session::results::read_results(&results).unwrap();
        let score = nanoforce::session::score::score(&truth, &rows);
        assert_eq!(score.detect_rate, 1.0, "{name}: {score:?}");
        assert_eq!(score.false_detections, 0, "{name}: {score:?}");
        assert!(score.angle_err_p95_deg < 0.15, "{name}: {score:?}");
    }
    assert_eq!(std::fs::read_dir(&overlays).unwrap().count(), 12);
}
