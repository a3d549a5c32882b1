//! Sessions written by the scene module have the session layout of docs/conventions.md,
//! parse with the project's config loader, and generated sets span the conditions they
//! promise.

use std::path::Path;

use nanoforce::config::{Config, Threshold};
use nanoforce::daemon::lab::probe_trackers;
use nanoforce::scene::{suite, Entry, FrameFormat, Session, Style, ToolKind};
use nanoforce::vision::{Estimate, ProbeSet};

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn mixed_session_layout_parses_with_config_load() {
    let dir = tempfile::tempdir().expect("temp dir");
    let session = Session::mixed(42, 12, 640, 480);
    let truths = session.write(dir.path(), FrameFormat::Png).expect("write");
    let cfg = Config::load(&dir.path().join("probe.toml")).expect("probe.toml parses");
    let cantilever = cfg.probes[0]
        .cantilever
        .expect("the session's probe.toml has [cantilever]");
    assert!((cantilever.length_um - session.probe().length_um).abs() < 1e-9);
    let force_scale = session.probe().cantilever().force_scale_nn();
    assert!((cantilever.force_scale_nn() / force_scale - 1.0).abs() < 1e-12);
    let cal = cfg.probes[0]
        .tracker
        .calibration
        .clone()
        .expect("calibration");
    assert_eq!(cal.reference_image, dir.path().join("reference.png"));
    assert!(cal.reference_image.exists());
    assert_eq!(cfg.probes[0].tracker.threshold, Threshold::Otsu);
    let csv = read(&dir.path().join("truth.csv"));
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("frame,detected,angle_deg,force_nN,tip_x,tip_y,magnification,px_per_um,style,t_s")
    );
    for (k, (line, truth)) in lines.zip(&truths).enumerate() {
        let cols: Vec<&str> = line.split(',').collect();
        assert_eq!(cols.len(), 10, "{line}");
        assert_eq!(cols[0], format!("frame_{k:05}.png"));
        assert!(dir.path().join("frames").join(cols[0]).exists());
        assert_eq!(cols[1], if truth.probe_in_view { "1" } else { "0" });
        let angle: f64 = cols[2].parse().expect("angle");
        if truth.probe_in_view {
            assert!((angle - truth.angle_deg).abs() < 1e-6);
        } else {
            assert!(angle.is_nan());
        }
        let t_s: f64 = cols[9].parse().expect("t_s");
        assert!((t_s - k as f64 / 60.0).abs() < 1e-6);
    }
}

/// A session of two rigid tools is written as a lab folder: its probe.toml gives each
/// tool as a `[[probe]]` of named edges, without a cantilever and searched over the
/// frames' scales, and the trackers `replay` builds from that file track the written
/// frames exactly as the session's own trackers track them.
#[test]
fn a_session_of_two_tools_is_written_as_it_is_tracked() {
    let dir = tempfile::tempdir().expect("temp dir");
    let kinds = [ToolKind::Needle, ToolKind::Gripper];
    let session = Session::two_tools(kinds, 5, 16);
    session.write(dir.path(), FrameFormat::Png).expect("write");
    let cfg = Config::load(&dir.path().join("probe.toml")).expect("probe.toml parses");
    for (probe, kind) in cfg.probes.iter().zip(kinds) {
        assert!(probe.cantilever.is_none() && !probe.felt, "{}", probe.name);
        let cal = probe.tracker.calibration.as_ref().expect("calibration");
        assert_eq!(cal.apex, Some(kind.apex_edges().map(String::from)));
        let names: Vec<&str> = cal.edges.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, kind.edge_names());
        assert!(probe.tracker.scale_range.is_some());
    }
    let mut from_file = probe_trackers(&cfg).expect("trackers from probe.toml");
    let mut own = ProbeSet::new(session.trackers().expect("trackers"), &[(); 2]);
    let mut detected = 0;
    for (k, name) in session.probe_names().iter().enumerate() {
        assert!(
            dir.path().join(format!("truth.{name}.csv")).is_file(),
            "{k}"
        );
    }
    for k in 0..session.frames.len() {
        let path = dir.path().join(format!("frames/frame_{k:05}.png"));
        let frame = image::open(&path).expect("frame").to_luma8();
        let (mut a, mut b) = ([Estimate::default(); 2], [Estimate::default(); 2]);
        from_file.track(&frame, &mut a);
        own.track(&frame, &mut b);
        for (a, b) in a.iter().zip(&b) {
            assert_eq!(a.detected, b.detected, "frame {k}");
            assert_eq!(a.angle_deg, b.angle_deg, "frame {k}");
            assert!(a.force_nn.is_none());
            detected += usize::from(a.detected);
        }
    }
    assert!(
        detected >= 16,
        "{detected} detections in 16 frames of two tools"
    );
}

#[test]
fn calibration_clicks_are_within_a_pixel_of_the_true_edges() {
    let session = Session::mixed(7, 1, 640, 480);
    let (_, truth) = nanoforce::scene::render(&session.reference);
    let edges = truth.edges.expect("reference shows the probe");
    let clicks = session.clicks();
    for (points, edge) in [
        (&clicks.red, edges.red),
        (&clicks.blue, edges.blue),
        (&clicks.green, edges.green),
    ] {
        assert_eq!(points.len(), 3);
        for p in points {
            let d = edge.signed_distance(*p).abs();
            assert!(d <= 1.05, "click {p:?} is {d} px from its edge");
        }
        // Off, as a person's clicks are: not all exactly on the line.
        assert!(points.iter().any(|p| edge.signed_distance(*p).abs() > 0.05));
    }
}

#[test]
fn sessions_are_deterministic_and_formats_decode() {
    let a = tempfile::tempdir().expect("temp dir");
    let b = tempfile::tempdir().expect("temp dir");
    let session = Session::sequence(5, 6, 640, 480);
    session
        .write(a.path(), FrameFormat::Tiff16)
        .expect("write a");
    Session::sequence(5, 6, 640, 480)
        .write(b.path(), FrameFormat::Tiff16)
        .expect("write b");
    for name in ["probe.toml", "truth.csv"] {
        assert_eq!(read(&a.path().join(name)), read(&b.path().join(name)));
    }
    let frame = a.path().join("frames/frame_00003.tif");
    let bytes_a = std::fs::read(&frame).expect("frame");
    assert_eq!(
        bytes_a,
        std::fs::read(b.path().join("frames/frame_00003.tif")).expect("frame")
    );
    let img = image::open(&frame).expect("tiff decodes");
    assert_eq!(img.color(), image::ColorType::L16);
    assert!(matches!(
        Config::load(&a.path().join("probe.toml"))
            .expect("parses")
            .probes[0]
            .tracker
            .threshold,
        Threshold::Level(_)
    ));
}

#[test]
fn sequences_press_and_release_without_angle_jumps() {
    let session = Session::sequence(11, 240, 640, 480);
    let angles: Vec<f64> = session.frames.iter().map(|f| f.angle_deg).collect();
    let max = angles.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let min = angles.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(max > 11.0 && min < -11.0, "presses both ways: {min}..{max}");
    for pair in angles.windows(2) {
        assert!((pair[1] - pair[0]).abs() < 3.5, "angle jumped {pair:?}");
    }
    let jumps = session
        .frames
        .windows(2)
        .filter(|p| p[0].magnification != p[1].magnification)
        .count();
    assert!(jumps >= 2, "magnification changes: {jumps}");
}

#[test]
fn suite_spans_every_condition() {
    let sessions = suite(2024, 12, 50);
    let frames: Vec<_> = sessions.iter().flat_map(|s| s.frames.iter()).collect();
    assert_eq!(frames.len(), 600);
    let entries: Vec<Entry> = sessions.iter().map(|s| s.reference.entry).collect();
    assert!(entries.contains(&Entry::Left) && entries.contains(&Entry::Right));
    let bases = sessions.iter().map(|s| s.reference.base_deg);
    assert!(bases.clone().all(|b| b.abs() <= 35.0));
    assert!(bases.clone().any(|b| b > 15.0) && bases.clone().any(|b| b < -15.0));
    let mags = frames.iter().map(|f| f.magnification);
    assert!(mags.clone().all(|m| (1000.0..=8000.0).contains(&m)));
    assert!(mags.clone().any(|m| m < 1300.0) && mags.clone().any(|m| m > 6000.0));
    let angles = frames.iter().map(|f| f.angle_deg);
    assert!(angles.clone().all(|a| a.abs() <= 20.0));
    assert!(angles.clone().any(|a| a > 18.0) && angles.clone().any(|a| a < -18.0));
    for style in Style::ALL {
        let n = frames
            .iter()
            .filter(|f| f.look.style_name == style.name())
            .count();
        assert_eq!(n, 150, "{style:?}");
    }
    let blanks = frames.iter().filter(|f| f.blank).count();
    assert!((10..=60).contains(&blanks), "blank frames: {blanks}");
    assert!(frames.iter().any(|f| f.width == 1280) && frames.iter().any(|f| f.width == 640));
    assert_eq!(suite(2024, 12, 50), sessions, "deterministic from the seed");
}
