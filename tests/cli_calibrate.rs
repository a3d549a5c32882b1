//! `nanoforce calibrate`: the printed block is a valid calibration, the reference frame
//! then reads zero, and bad clicks are clear errors.
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

fn calibrate(dir: &Path, extra: &[&str]) -> std::process::Output {
    let reference =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/samples/mixed/reference.png");
    std::fs::copy(&reference, dir.join("reference.png")).unwrap();
    Command::new(BIN)
        .arg("calibrate")
        .arg("--image")
        .arg(dir.join("reference.png"))
        .args(["--red", "156.8,33.4", "228.3,57.3", "299.9,81.0"])
        .args(["--blue", "230.7,114.2", "245.4,153.4", "260.6,192.0"])
        .args(["--green", "282.5,199.8", "298.4,170.9", "314.8,142.9"])
        .args(extra)
        .output()
        .unwrap()
}

/// Asserts that a results row (from [`replay_reference`]) detects the probe at 0 deg
/// to within 0.01 deg: the reference frame reads zero.
fn assert_reads_zero(row: &[String]) {
    assert_eq!(row[1], "1", "{row:?}");
    let angle: f64 = row[2].parse().unwrap();
    assert!(angle.abs() < 0.01, "the reference frame reads {angle} deg");
}

/// Replays `reference` alone with a probe.toml of `config` text (in `dir`); the
/// results row's fields.
fn replay_reference(dir: &Path, config: &str, reference: &Path) -> Vec<String> {
    let path = dir.join("probe.toml");
    std::fs::write(&path, config).unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    std::fs::copy(reference, frames.join("ref.png")).unwrap();
    let csv = dir.join("out.csv");
    let out = Command::new(BIN)
        .arg("replay")
        .arg(&frames)
        .arg("--config")
        .arg(&path)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    text.lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(String::from)
        .collect()
}

#[test]
fn printed_block_calibrates_and_the_reference_reads_zero() {
    let dir = tempfile::tempdir().unwrap();
    let overlay = dir.path().join("check.png");
    let out = calibrate(dir.path(), &["--overlay", overlay.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let block = String::from_utf8(out.stdout).unwrap();
    assert!(block.starts_with("[tracker.calibration]\n"), "{block}");
    for edge in ["red", "blue", "green"] {
        assert!(
            block.contains(&format!("#   {edge}")),
            "refined {edge} orientation: {block}"
        );
    }
    // Whether the beam's thickness was measured, and what follows when not.
    assert!(block.contains("\n# Beam thickness"), "{block}");
    assert!(image::open(&overlay).is_ok(), "overlay written");
    let row = replay_reference(
        dir.path(),
        &format!("[cantilever]\nlength_um = 434.675\nspring_constant_n_per_m = 0.06\n\n{block}"),
        &dir.path().join("reference.png"),
    );
    // Calibration refines each edge on its own; tracking fits them jointly, with the
    // beam's bend held near what the elastica predicts. The two agree to well under the
    // tracker's own error on a sample frame (a few hundredths of a degree).
    assert_reads_zero(&row);
}

#[test]
fn clicks_outside_the_image_and_bad_syntax_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = calibrate(dir.path(), &["--red", "900,10", "950,20"]);
    // clap takes the last --red; it is outside the 640x480 frame.
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("outside"), "{err}");
    let out = Command::new(BIN)
        .args(["calibrate", "--image", "x.png", "--red", "1;2", "3,4"])
        .args(["--blue", "1,2", "3,4", "--green", "1,2", "3,4"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("\"1;2\" is not X,Y"),
        "{err}"
    );
    let out = Command::new(BIN)
        .args([
            "calibrate",
            "--image",
            "/nonexistent.png",
            "--red",
            "1,2",
            "3,4",
        ])
        .args(["--blue", "1,2", "3,4", "--green", "1,2", "3,4"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("/nonexistent.png"),
        "{err}"
    );
    // The search window accepts what [tracker] window_deg accepts, no more.
    for bad in ["0.5", "46", "nan"] {
        let out = calibrate(dir.path(), &["--window-deg", bad]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("--window-deg must be 1 to 45 deg"),
            "{bad}: {err}"
        );
    }
}

#[test]
fn clicks_and_apex_counted_from_the_corner() {
    let apex = |block: &str| -> [f64; 2] {
        let line = block
            .lines()
            .find(|l| l.starts_with("# Apex"))
            .unwrap_or_else(|| panic!("{block}"));
        let inner = &line[line.rfind('(').unwrap() + 1..line.rfind(')').unwrap()];
        let v: Vec<f64> = inner
            .split(',')
            .map(|v| v.trim().parse().unwrap())
            .collect();
        [v[0], v[1]]
    };
    let dir = tempfile::tempdir().unwrap();
    let out = calibrate(dir.path(), &[]);
    assert!(out.status.success());
    let centre = String::from_utf8(out.stdout).unwrap();
    assert!(!centre.contains("pixel_origin"), "{centre}");
    let out = calibrate(dir.path(), &["--pixel-origin", "corner"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let corner = String::from_utf8(out.stdout).unwrap();
    // The same clicks, read from the corner, sit half a pixel up and left; the printed
    // apex is counted from the corner again. The refined edges barely depend on where
    // the clicks start them, so the apex reads half a pixel more.
    assert!(
        corner.contains("[tracker] needs pixel_origin = \"corner\""),
        "{corner}"
    );
    assert!(
        corner.contains("red = [[156.8, 33.4]"),
        "clicks as given: {corner}"
    );
    let (a, b) = (apex(&centre), apex(&corner));
    for k in 0..2 {
        assert!((b[k] - a[k] - 0.5).abs() < 0.05, "{a:?} -> {b:?}");
    }
    let out = calibrate(dir.path(), &["--pixel-origin", "middle"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("\"middle\""), "{err}");
}

#[test]
fn the_overlay_never_overwrites_the_image() {
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("reference.png");
    for overlay in [
        image.clone(),
        dir.path().join("./reference.png"),
        dir.path().join("sub/../reference.png"),
    ] {
        let out = calibrate(dir.path(), &["--overlay", overlay.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("is the --image itself"),
            "{overlay:?}: {err}"
        );
        assert!(out.stdout.is_empty(), "nothing printed before the refusal");
        let reference =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/samples/mixed/reference.png");
        assert_eq!(
            std::fs::read(&image).unwrap(),
            std::fs::read(reference).unwrap(),
            "the reference frame is untouched"
        );
    }
}

/// The refined orientation of each edge in a printed block, degrees.
fn refined(block: &str) -> Vec<f64> {
    ["red", "blue", "green"]
        .iter()
        .map(|edge| {
            let line = block
                .lines()
                .find(|l| l.starts_with(&format!("#   {edge} ")))
                .unwrap_or_else(|| panic!("no refined {edge}: {block}"));
            line.split_whitespace().nth(2).unwrap().parse().unwrap()
        })
        .collect()
}

#[test]
fn auto_calibration_prints_the_block_the_clicks_give() {
    let dir = tempfile::tempdir().unwrap();
    let overlay = dir.path().join("auto.png");
    let hand = calibrate(dir.path(), &["--overlay", overlay.to_str().unwrap()]);
    let hand = refined(&String::from_utf8(hand.stdout).unwrap());
    let run = |extra: &[&str]| {
        Command::new(BIN)
            .arg("calibrate")
            .arg("--image")
            .arg(dir.path().join("reference.png"))
            .args(["--overlay", overlay.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap()
    };
    // One click near the apex, and none (the probe enters from the left).
    for extra in [&["--auto", "--apex", "271,214"][..], &["--auto"][..]] {
        std::fs::remove_file(&overlay).ok();
        let out = run(extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{extra:?}: {err}");
        let block = String::from_utf8(out.stdout).unwrap();
        assert!(block.starts_with("[tracker.calibration]\n"), "{block}");
        for key in ["red = [[", "blue = [[", "green = [["] {
            assert!(block.contains(key), "{key}: {block}");
        }
        for (a, h) in refined(&block).iter().zip(&hand) {
            assert!((a - h).abs() <= 0.01, "{extra:?}: {a} against {h}\n{block}");
        }
        assert!(image::open(&overlay).is_ok(), "overlay written");
    }
    let out = run(&["--auto", "--apex", "600,300"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("auto-calibration: ") && err.contains("not found near the apex"),
        "{err}"
    );
    let out = run(&["--auto", "--red", "1,2", "3,4"]);
    assert!(!out.status.success(), "--auto with clicks is refused");
}

#[test]
fn a_rigid_probe_is_calibrated_from_its_named_edges() {
    use nanoforce::scene::{render_tool_into, tool_suite, ToolKind};
    let dir = tempfile::tempdir().unwrap();
    // A needle of the renderer's tool suite, with its clicks.
    let session = &tool_suite(ToolKind::ALL[0], 41, 1, 2, 0)[0];
    let mut reference = image::GrayImage::new(1, 1);
    render_tool_into(&session.reference, &[], &mut reference);
    let image = dir.path().join("needle.png");
    reference.save(&image).unwrap();
    let overlay = dir.path().join("needle-check.png");
    let edge_args: Vec<String> = session
        .clicks
        .iter()
        .flat_map(|(name, points)| {
            let points: Vec<String> = points
                .iter()
                .map(|p| format!("{:.2},{:.2}", p[0], p[1]))
                .collect();
            ["--edge".to_string(), format!("{name}={}", points.join(" "))]
        })
        .collect();
    let calibrate = |extra: &[&str]| {
        Command::new(BIN)
            .arg("calibrate")
            .arg("--image")
            .arg(&image)
            .args(&edge_args)
            .args(["--overlay", overlay.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap()
    };
    // A refused calibration's message.
    let refused = |extra: &[&str]| {
        let out = calibrate(extra);
        assert!(!out.status.success(), "{extra:?} refused");
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let apex = format!("{},{}", session.apex[0], session.apex[1]);
    let out = calibrate(&["--apex-edges", &apex]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let block = String::from_utf8(out.stdout).unwrap();
    assert!(block.starts_with("[tracker.calibration]\n"), "{block}");
    assert!(block.contains("\n[tracker.calibration.edges]\n"), "{block}");
    for (name, _) in &session.clicks {
        assert!(block.contains(&format!("\n{name} = [[")), "{name}: {block}");
        assert!(block.contains(&format!("\n#   {name} ")), "{name}: {block}");
    }
    assert!(image::open(&overlay).is_ok(), "overlay written");
    // The block is a probe's calibration: the reference reads zero, and without a
    // cantilever there is no force.
    let row = replay_reference(dir.path(), &block, &image);
    assert_reads_zero(&row);
    assert_eq!(row[3], "", "no cantilever, no force: {row:?}");
    // An apex edge that is not among the named ones is named in the error.
    let err = refused(&["--apex-edges", "upper,tip"]);
    assert!(err.contains("apex edge \"tip\""), "{err}");
    // So is an edge given twice.
    let err = refused(&[&edge_args[0], &edge_args[1], "--apex-edges", &apex]);
    assert!(err.contains("is given twice"), "{err}");
    // The pyramid's threshold plays no part in a rigid calibration: refused, not
    // silently ignored.
    let err = refused(&["--apex-edges", &apex, "--threshold", "100"]);
    assert!(
        err.contains("--threshold") && err.contains("cannot be used with"),
        "{err}"
    );
}

#[test]
fn a_rigid_probe_is_calibrated_from_one_pixel_near_its_tip_point() {
    use nanoforce::scene::{render_tool_into, tool_suite, ToolKind};
    let dir = tempfile::tempdir().unwrap();
    let session = &tool_suite(ToolKind::ALL[0], 41, 1, 2, 0)[0];
    let mut reference = image::GrayImage::new(1, 1);
    let truth = render_tool_into(&session.reference, &[], &mut reference);
    let image = dir.path().join("needle.png");
    reference.save(&image).unwrap();
    let overlay = dir.path().join("needle-check.png");
    let calibrate = |extra: &[&str]| {
        Command::new(BIN)
            .arg("calibrate")
            .arg("--image")
            .arg(&image)
            .args(["--overlay", overlay.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap()
    };
    let near = format!(
        "{:.0},{:.0}",
        truth.apex_px[0] + 1.0,
        truth.apex_px[1] - 1.0
    );
    let out = calibrate(&["--auto", "--rigid", "--apex", &near]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let block = String::from_utf8(out.stdout).unwrap();
    assert!(block.contains("\napex = [\"e"), "{block}");
    for name in ["e1", "e2", "e3"] {
        assert!(block.contains(&format!("\n{name} = [[")), "{name}: {block}");
    }
    assert!(image::open(&overlay).is_ok(), "overlay written");
    // The block is the probe's calibration: the reference reads zero.
    let row = replay_reference(dir.path(), &block, &image);
    assert_reads_zero(&row);
    // A pixel in the background far from the needle finds no probe, and says so.
    let out = calibrate(&["--auto", "--rigid", "--apex", "20,20"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("auto-calibration: "),
        "{err}"
    );
    // --rigid without --auto is refused by the parser.
    let out = calibrate(&["--rigid", "--apex", &near]);
    assert!(!out.status.success());
    // Without --apex the needle, the body entering from a side, gives its tip point:
    // a corner of its end, the block again reading the reference at zero.
    let out = calibrate(&["--auto", "--rigid"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let block = String::from_utf8(out.stdout).unwrap();
    let row = replay_reference(dir.path(), &block, &image);
    assert_reads_zero(&row);
    // A frame without a body entering from a side has no tip point to take.
    let blank = dir.path().join("blank.png");
    image::GrayImage::from_pixel(320, 240, image::Luma([90]))
        .save(&blank)
        .unwrap();
    let out = Command::new(BIN)
        .args(["calibrate", "--auto", "--rigid", "--image"])
        .arg(&blank)
        .args(["--overlay", overlay.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--apex"), "{err}");
}
