//! Rigid probes of named edges (a tungsten needle, a tipless cantilever, a gripper jaw;
//! docs/rigid-probes.md) tracked over the renderer's tool suites: sessions of one or
//! two SEM conditions each, over synthetic and real backgrounds (`tests/data/real-sem`),
//! each calibrated from its reference's clicks.
//! Targets per kind over at least 300 frames with the tool in view: detection >= 99.5 %,
//! no detection on a frame without it, angle error median <= 0.03 deg and p95 <= 0.10
//! deg; the reported standard error covers the error (median |error| / sigma in
//! 0.5-0.9, at most 0.5 % beyond 4 sigma).
//!
//! Each tracker searches the scales a lab would state for these sessions
//! (`tracker.scale_range`, see `scales`).
//!
//! `TOOL_SEED` picks another suite (the committed bounds hold on the default seed; a
//! held-out seed is the check that they are not tuned to it). For looking into a
//! miss: `RIGID_DEBUG=1` prints each session's template and each missed or tail frame,
//! and `ONLY_FRAME=k` tracks frame `k` of each session alone and writes it to
//! `target/tmp/rigid-frames/<reference seed>_<k>.png`.

mod tracker_support;

use image::GrayImage;
use nanoforce::scene::adversarial::{self, Adversary, Decoy};
use nanoforce::scene::rng::{sub_seed, Rng};
use nanoforce::scene::{self, render_tool_into, tool_suite, ToolKind, ToolSession, TOOL_MAG_RATIO};
use nanoforce::vision::{
    auto_calibrate_rigid, calibrate_rigid, Estimate, Pose, RigidTemplate, RigidTracker, ScaleRange,
    DEFAULT_WINDOW_DEG, RIGID_SCALES,
};
use tracker_support::rendered::real_crops;
use tracker_support::MISPLACED_PX;

/// Sessions per kind and frames per session: 16 x 20 = 320 frames, about 300 in view.
const SESSIONS: usize = 16;
const FRAMES: usize = 20;

/// What a kind's suite measured.
#[derive(Debug, Default)]
struct Measured {
    in_view: usize,
    /// Frames of other kinds of tool tracked as this one.
    other_tools: usize,
    detected: usize,
    false_detections: usize,
    errors: Vec<f64>,
    apex_errors: Vec<f64>,
    /// |reported scale / true scale - 1|, or infinity for a detection reporting none.
    scale_errors: Vec<f64>,
    ratios: Vec<f64>,
    misses: Vec<String>,
    /// Misses that the fit from the true pose refuses too: the verification's, not
    /// the search's.
    refused_at_truth: usize,
    /// Detections whose tip point lies more than [`MISPLACED_PX`] from the truth.
    misplaced: Vec<String>,
}

/// The scales the lab states (`tracker.scale_range`): the suite's magnifications over
/// the reference's, known to the lab to 10 %. `TOOL_SCALES=widest` searches the
/// widest range instead, which cannot tell a needle from a jaw of its taper at half
/// the size.
fn scales() -> ScaleRange {
    match std::env::var("TOOL_SCALES").as_deref() {
        Ok("widest") => RIGID_SCALES,
        _ => ScaleRange::new(TOOL_MAG_RATIO[0] / 1.1, TOOL_MAG_RATIO[1] * 1.1),
    }
}

/// A tracker of `template` over the scales the lab states.
fn lab_tracker(template: RigidTemplate) -> RigidTracker {
    RigidTracker::new(template, DEFAULT_WINDOW_DEG)
        .with_scales(scales())
        .unwrap()
}

fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * q).round() as usize]
}

/// The suites' seed: `TOOL_SEED`, or 41.
fn tool_seed() -> u64 {
    std::env::var("TOOL_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(41)
}

/// The template calibrated on `session`'s reference (rendered into `frame`) from its
/// clicks.
fn calibrated(session: &ToolSession, crops: &[GrayImage], frame: &mut GrayImage) -> RigidTemplate {
    render_tool_into(&session.reference, crops, frame);
    calibrate_rigid(frame, &clicks_of(session), session.apex)
        .unwrap_or_else(|e| panic!("{} reference: {e}", session.kind.name()))
}

/// A session's clicks as calibration takes them.
fn clicks_of(session: &ToolSession) -> Vec<(String, Vec<[f64; 2]>)> {
    session
        .clicks
        .iter()
        .map(|(name, points)| (name.to_string(), points.clone()))
        .collect()
}

/// Tracks `session`'s frames with a tracker calibrated on its reference, and the
/// `others`' frames (other kinds of tool: none of them is this probe) with the same.
fn run(session: &ToolSession, others: &[&ToolSession], crops: &[GrayImage], out: &mut Measured) {
    let mut frame = GrayImage::new(1, 1);
    let template = calibrated(session, crops, &mut frame);
    if std::env::var("RIGID_DEBUG").is_ok() {
        let t = &template;
        println!(
            "session {} seed {} {}x{} style {} probe {:.0} bg {:.0} noise {:.1} real {} needle {} edges {:?}",
            session.kind.name(),
            session.reference.seed,
            session.reference.width,
            session.reference.height,
            session.reference.look.style_name,
            session.reference.look.probe,
            session.reference.look.background,
            session.frames[0].look.noise_sigma,
            session.reference.look.real.is_some(),
            session.reference.look.needle.is_some(),
            t.edges
                .iter()
                .map(|e| format!("{} dir {:.2} len {:.1} off {:.1} ext {:.1}..{:.1} {:?} pol {} step {:.1}", e.name, e.normal[1].atan2(e.normal[0]).to_degrees(), e.extent[1] - e.extent[0], e.offset, e.extent[0], e.extent[1], e.open, e.polarity, e.step))
                .collect::<Vec<_>>()
        );
    }
    let mut tracker = lab_tracker(template);
    let only: Option<usize> = std::env::var("ONLY_FRAME")
        .ok()
        .and_then(|s| s.parse().ok());
    for (k, spec) in session.frames.iter().enumerate() {
        if only.is_some_and(|o| o != k) {
            continue;
        }
        let truth = render_tool_into(spec, crops, &mut frame);
        if only.is_some() {
            let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("rigid-frames");
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join(format!("{}_{k}.png", session.reference.seed));
            frame
                .save(&path)
                .unwrap_or_else(|err| panic!("{}: {err}", path.display()));
        }
        let e: Estimate = tracker.track(&frame);
        if !truth.in_view {
            if e.detected && std::env::var("RIGID_DEBUG").is_ok() {
                println!(
                    "   false on blank frame {k}: scale {:.3}",
                    e.scale.unwrap_or(f64::NAN)
                );
            }
            out.false_detections += usize::from(e.detected);
            continue;
        }
        out.in_view += 1;
        if !e.detected {
            if std::env::var("RIGID_DEBUG").is_ok() {
                println!(
                    "   miss {k}: {:?} truth angle {:.2} apex {:?} scale {:.3}",
                    e.miss.map(|m| m.name()),
                    truth.angle_deg,
                    truth.apex_px,
                    spec.magnification / session.reference.magnification
                );
            }
            let truth_pose = Pose {
                psi: -truth.angle_deg.to_radians(),
                scale: spec.magnification / session.reference.magnification,
                apex: truth.apex_px,
            };
            let at_truth = tracker.track_from(&frame, truth_pose);
            out.refused_at_truth += usize::from(!at_truth.detected);
            out.misses.push(format!(
                "{} frame {k}: {} ({})",
                session.kind.name(),
                e.miss.map_or("", |m| m.name()),
                match at_truth.miss {
                    Some(m) => format!("from the true pose too: {}", m.name()),
                    None => "by the search: the true pose verifies".into(),
                }
            ));
            continue;
        }
        out.detected += 1;
        let true_scale = spec.magnification / session.reference.magnification;
        out.scale_errors.push(
            e.scale
                .map_or(f64::INFINITY, |s| (s / true_scale - 1.0).abs()),
        );
        let err = e.angle_deg.unwrap() - truth.angle_deg;
        out.errors.push(err.abs());
        out.ratios.push(err.abs() / e.angle_sigma_deg.unwrap());
        if std::env::var("RIGID_DEBUG").is_ok() && err.abs() > 4.0 * e.angle_sigma_deg.unwrap() {
            println!(
                "   tail {k}: err {err:.4} sigma {:.4} angle {:.2} scale {:.3} apex {:?}",
                e.angle_sigma_deg.unwrap(),
                truth.angle_deg,
                spec.magnification / session.reference.magnification,
                truth.apex_px
            );
        }
        let a = e.apex_px.unwrap();
        let apex_error = (a[0] - truth.apex_px[0]).hypot(a[1] - truth.apex_px[1]);
        out.apex_errors.push(apex_error);
        if apex_error > MISPLACED_PX {
            out.misplaced.push(format!(
                "{} frame {k}: apex {apex_error:.1} px off, scale {:.3} (true {true_scale:.3})",
                session.kind.name(),
                e.scale.unwrap_or(f64::NAN)
            ));
        }
    }
    for other in others {
        for (k, spec) in other.frames.iter().enumerate() {
            render_tool_into(spec, crops, &mut frame);
            out.other_tools += 1;
            let e = tracker.track(&frame);
            if e.detected && std::env::var("RIGID_DEBUG").is_ok() {
                println!(
                    "   false on a {} frame {k}: scale {:.3} angle {:.2} confidence {:.2}",
                    other.kind.name(),
                    e.scale.unwrap_or(f64::NAN),
                    e.angle_deg.unwrap_or(f64::NAN),
                    e.confidence
                );
            }
            out.false_detections += usize::from(e.detected);
        }
    }
}

fn measure(kind: ToolKind) -> Measured {
    let seed = tool_seed();
    let crops = real_crops();
    let mut m = Measured::default();
    let suites: Vec<Vec<ToolSession>> = ToolKind::ALL
        .iter()
        .map(|&k| tool_suite(k, seed, SESSIONS, FRAMES, crops.len()))
        .collect();
    let own = ToolKind::ALL.iter().position(|&k| k == kind).unwrap();
    for (i, session) in suites[own].iter().enumerate() {
        let others: Vec<&ToolSession> = (0..suites.len())
            .filter(|&k| k != own)
            .map(|k| &suites[k][i])
            .collect();
        run(session, &others, &crops, &mut m);
    }
    let rate = m.detected as f64 / m.in_view as f64;
    println!(
        "{}: in view {}, detected {:.4}, false {} (of {} other tools' frames and blanks), angle median {:.4} p95 {:.4} max {:.4} deg, \
         apex median {:.3} px, |err|/sigma median {:.3}, beyond 4 sigma {}",
        kind.name(),
        m.in_view,
        rate,
        m.false_detections,
        m.other_tools,
        quantile(&m.errors, 0.5),
        quantile(&m.errors, 0.95),
        quantile(&m.errors, 1.0),
        quantile(&m.apex_errors, 0.5),
        quantile(&m.ratios, 0.5),
        m.ratios.iter().filter(|r| **r > 4.0).count()
    );
    println!(
        "{}: scale error median {:.4}, p99 {:.4}, max {:.4}",
        kind.name(),
        quantile(&m.scale_errors, 0.5),
        quantile(&m.scale_errors, 0.99),
        quantile(&m.scale_errors, 1.0)
    );
    println!(
        "{}: {} missed, {} of them refused from the true pose too",
        kind.name(),
        m.misses.len(),
        m.refused_at_truth
    );
    for miss in &m.misses {
        println!("  missed {miss}");
    }
    for d in &m.misplaced {
        println!("  misplaced {d}");
    }
    m
}

/// Bounds measured on the default seed (and the held-out seed 97), below the targets
/// where the tracker does not reach them yet (docs/rigid-probes.md): detection
/// 99.3-100 % (held-out 99.7-100 %), no false detection at the scales the lab states,
/// up to 0.7 % of detections beyond 4 sigma.
const MIN_DETECTION: f64 = 0.993;
const MAX_BEYOND_4_SIGMA: f64 = 0.007;

fn check(kind: ToolKind) {
    let m = measure(kind);
    assert!(
        m.in_view >= 290,
        "{}: {} frames in view",
        kind.name(),
        m.in_view
    );
    let rate = m.detected as f64 / m.in_view as f64;
    assert!(
        rate >= MIN_DETECTION,
        "{}: detection {rate:.4}",
        kind.name()
    );
    assert!(
        m.false_detections == 0,
        "{}: {} false",
        kind.name(),
        m.false_detections
    );
    assert!(
        m.misplaced.is_empty(),
        "{}: misplaced {:?}",
        kind.name(),
        m.misplaced
    );
    let (median, p95) = (quantile(&m.errors, 0.5), quantile(&m.errors, 0.95));
    assert!(
        median <= 0.03,
        "{}: angle median {median:.4} deg",
        kind.name()
    );
    assert!(p95 <= 0.10, "{}: angle p95 {p95:.4} deg", kind.name());
    // The scale is measured by the edges away from the apex: 0.04-0.13 % off in the
    // median, 2.9 % at worst over seeds 41, 97 and 7.
    let scale_max = quantile(&m.scale_errors, 1.0);
    assert!(
        scale_max <= 0.04,
        "{}: a scale {scale_max:.4} off",
        kind.name()
    );
    let ratio = quantile(&m.ratios, 0.5);
    assert!(
        (0.5..=0.9).contains(&ratio),
        "{}: |error|/sigma median {ratio:.3}",
        kind.name()
    );
    let beyond = m.ratios.iter().filter(|r| **r > 4.0).count();
    assert!(
        beyond as f64 <= MAX_BEYOND_4_SIGMA * m.ratios.len() as f64,
        "{}: {beyond} detections beyond 4 sigma",
        kind.name()
    );
}

#[test]
fn a_needle_is_tracked_over_its_suite() {
    check(ToolKind::Needle);
}

#[test]
fn a_tipless_cantilever_is_tracked_over_its_suite() {
    check(ToolKind::Tipless);
}

#[test]
fn a_gripper_jaw_is_tracked_over_its_suite() {
    check(ToolKind::Gripper);
}

/// Frames of each kind of the adversarial generator per tool session, and windows of
/// real SEM frames.
const DECOY_FRAMES: usize = 10;
/// Offsets the decoys' frame seeds from the ones tests/tracker_adversarial.rs derives
/// the same way, so a seed both suites use shows different frames in each.
const DECOY_STREAM: u64 = 77;

/// Every kind's trackers (its 16 sessions', calibrated on their references) on frames
/// without the tool: the adversarial generator's kinds (tests/tracker_adversarial.rs),
/// made for the AFM suite's sessions, and windows of real SEM frames: 2,880 frames per
/// seed. None is detected, but for the tipless lever on frames that show its outline:
/// a tipless lever is a strip with a square end, and the random shapes' beam-like
/// strips and the AFM levers' beams (another probe, a tip under a patch) are such
/// strips; those detections are reported, not refused (docs/rigid-probes.md).
#[test]
fn no_tool_is_found_on_frames_without_it() {
    let seed = tool_seed();
    let crops = real_crops();
    let afm = scene::suite(seed, 6, 1);
    let mut adversary = Adversary::new();
    let mut frame = GrayImage::new(1, 1);
    let mut decoy = GrayImage::new(1, 1);
    let mut false_detections = Vec::new();
    let mut outlines = 0;
    for kind in ToolKind::ALL {
        for (i, session) in tool_suite(kind, seed, SESSIONS, 1, crops.len())
            .iter()
            .enumerate()
        {
            let mut tracker = lab_tracker(calibrated(session, &crops, &mut frame));
            let made_for = &afm[i % afm.len()];
            let mut found = |what: String, e: Estimate, strip: bool| {
                if !e.detected {
                    return;
                }
                println!(
                    "{} session {i}: {what} detected, scale {:?}",
                    kind.name(),
                    e.scale
                );
                if strip && kind == ToolKind::Tipless {
                    outlines += 1;
                } else {
                    false_detections.push(format!("{} session {i}: {what}", kind.name()));
                }
            };
            for d in Decoy::ALL {
                for k in 0..DECOY_FRAMES {
                    let frame_seed = sub_seed(
                        seed,
                        (1000 * i + 100 * d as usize + k) as u64 + DECOY_STREAM,
                    );
                    adversary.render_into(made_for, d, frame_seed, &mut decoy);
                    let strip = matches!(d, Decoy::Shapes | Decoy::OtherProbe | Decoy::Occluded);
                    found(
                        format!("{} frame {k}", d.name()),
                        tracker.track(&decoy),
                        strip,
                    );
                }
            }
            let mut rng = Rng::new(sub_seed(seed, 7000 + i as u64));
            let (w, h) = (session.reference.width, session.reference.height);
            for k in 0..DECOY_FRAMES {
                let window = adversarial::real_window(&crops, w, h, &mut rng);
                found(format!("real-sem frame {k}"), tracker.track(&window), false);
            }
        }
    }
    println!("tipless levers' outlines detected: {outlines}");
    assert!(false_detections.is_empty(), "{false_detections:#?}");
}

/// `nanoforce replay` of a needle session on disk: probe.toml names its edges and apex
/// and has no cantilever. Every frame with the needle in view is detected within the
/// targets' accuracy, the force column stays empty, a frame without the needle names
/// its refusal.
#[test]
fn replay_tracks_a_needle_named_in_its_config_and_reports_no_force() {
    let session = &tool_suite(ToolKind::Needle, 5, 1, 12, 0)[0];
    let dir = tempfile::tempdir().unwrap();
    let frames_dir = dir.path().join("frames");
    std::fs::create_dir(&frames_dir).unwrap();
    let mut frame = GrayImage::new(1, 1);
    render_tool_into(&session.reference, &[], &mut frame);
    frame.save(dir.path().join("reference.png")).unwrap();
    let mut truths = Vec::new();
    for (k, spec) in session.frames.iter().enumerate() {
        truths.push(render_tool_into(spec, &[], &mut frame));
        frame
            .save(frames_dir.join(format!("frame_{k:05}.png")))
            .unwrap();
    }
    // One more frame without the needle: the reference's background alone.
    let mut blank_spec = session.reference;
    blank_spec.blank = true;
    truths.push(render_tool_into(&blank_spec, &[], &mut frame));
    frame
        .save(frames_dir.join(format!("frame_{:05}.png", session.frames.len())))
        .unwrap();
    let points = |p: &[[f64; 2]]| {
        let items: Vec<String> = p
            .iter()
            .map(|q| format!("[{:.2}, {:.2}]", q[0], q[1]))
            .collect();
        format!("[{}]", items.join(", "))
    };
    let mut toml = format!(
        "[tracker]\n[tracker.calibration]\nreference_image = \"reference.png\"\n\
         apex = [\"{}\", \"{}\"]\n[tracker.calibration.edges]\n",
        session.apex[0], session.apex[1]
    );
    for (name, clicks) in &session.clicks {
        toml.push_str(&format!("{name} = {}\n", points(clicks)));
    }
    std::fs::write(dir.path().join("probe.toml"), &toml).unwrap();
    let replay = |config: &str, csv: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_nanoforce"))
            .arg("replay")
            .arg(&frames_dir)
            .arg("--config")
            .arg(dir.path().join(config))
            .arg("--csv")
            .arg(csv)
            .output()
            .unwrap()
    };
    let csv = dir.path().join("out.csv");
    let out = replay("probe.toml", &csv);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    assert_eq!(rows.len(), truths.len());
    for (row, truth) in rows.iter().zip(&truths) {
        let detected = row[col("detected")] == "1" || row[col("detected")] == "true";
        assert!(row[col("force_nN")].is_empty(), "{row:?}");
        if !truth.in_view {
            assert!(!detected, "{row:?}");
            assert!(!row[col("miss")].is_empty(), "{row:?}");
            continue;
        }
        assert!(detected, "{row:?}");
        let angle: f64 = row[col("angle_deg")].parse().unwrap();
        assert!(
            (angle - truth.angle_deg).abs() < 0.1,
            "{row:?} vs {}",
            truth.angle_deg
        );
    }
    // A scale range beyond the rigid search's is refused before any frame, by name.
    let wide = toml.replacen("[tracker]\n", "[tracker]\nscale_range = [0.3, 1.0]\n", 1);
    std::fs::write(dir.path().join("wide.toml"), wide).unwrap();
    let out = replay("wide.toml", &dir.path().join("wide.csv"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("tracker.scale_range = [0.3, 1]"),
        "{stderr}"
    );
}

/// Each reference's calibrated edges against the renderer's: degrees between the
/// directions, per kind and edge name, over the references of `seeds`.
fn reference_edge_errors(seeds: &[u64]) -> Vec<(String, Vec<f64>)> {
    let crops = real_crops();
    let mut frame = GrayImage::new(1, 1);
    let mut errors: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    for &seed in seeds {
        for kind in ToolKind::ALL {
            for session in tool_suite(kind, seed, SESSIONS, FRAMES, crops.len()) {
                let truth = render_tool_into(&session.reference, &crops, &mut frame);
                let clicks = clicks_of(&session);
                let template = calibrate_rigid(&frame, &clicks, session.apex).unwrap();
                for edge in &template.edges {
                    let seg = truth.edge(edge.name.as_str()).unwrap();
                    let d = [seg.to[0] - seg.from[0], seg.to[1] - seg.from[1]];
                    let sin = (edge.normal[0] * d[0] + edge.normal[1] * d[1]) / d[0].hypot(d[1]);
                    errors
                        .entry(format!("{} {}", kind.name(), edge.name.as_str()))
                        .or_default()
                        .push(sin.abs().asin().to_degrees());
                }
            }
        }
    }
    errors.into_iter().collect()
}

/// The references of the default and held-out seeds (96, 288 edges) read each edge's
/// direction to its truth: flanks to 0.002-0.005 deg in the median; the end faces,
/// 12-140 px long between two corners, to 0.02-0.28 deg, and 11 edges are more than
/// 0.5 deg off (23 with the stations beside a corner in the fit, whose runs reach
/// into it).
#[test]
fn reference_edges_are_read_to_their_truth() {
    let errors = reference_edge_errors(&[41, 97]);
    let mut off = 0;
    for (edge, e) in &errors {
        let median = quantile(e, 0.5);
        println!(
            "{edge}: median {median:.3} deg, max {:.3}",
            quantile(e, 1.0)
        );
        let bound = if edge.ends_with(" end") { 0.35 } else { 0.01 };
        assert!(median <= bound, "{edge}: median {median:.3} deg");
        off += e.iter().filter(|d| **d > 0.5).count();
    }
    assert!(off <= 14, "{off} edges more than 0.5 deg off");
}

/// `calibrate --auto --rigid` over the tool suites of the default and held-out seeds,
/// each reference calibrated two ways: from one pixel 1-2 px off its tip point (as a
/// person clicks near it), and from none (the corner of the body entering from a side
/// that reaches farthest). Its sessions are tracked with those templates and with the
/// clicked one. Measured from the pixel: 1 reference of 96 refused (a real-bright
/// tipless lever whose end face steps by 10 grey levels), the rest each finding its 3
/// edges (two grippers' flanks come in two pieces, joined as they calibrate to one
/// line); per kind and seed the automatic templates detect within 3 frames of the
/// clicked ones, at angle medians of 0.007-0.009 deg and p95 of 0.04-0.08 deg. From
/// none: 6 of 96 refused (outlines that fade over real backgrounds or leave the frame
/// from the corner taken); each tip point taken is one of the end face's two corners
/// (the clicked one on 56 of 90 references); detections within 3 frames of the clicks.
#[test]
fn automatic_calibration_tracks_as_the_clicks_do() {
    let crops = real_crops();
    let mut frame = GrayImage::new(1, 1);
    // References refused from the pixel, and from none.
    let mut refused = [0; 2];
    for seed in [41, 97] {
        for kind in ToolKind::ALL {
            // Per way: the clicked and the automatic template, over the sessions whose
            // reference that way calibrates.
            let mut measured: [(Measured, Measured); 2] = Default::default();
            for session in tool_suite(kind, seed, SESSIONS, FRAMES, crops.len()) {
                let truth = render_tool_into(&session.reference, &crops, &mut frame);
                let reference = frame.clone();
                let near = [
                    (truth.apex_px[0] + 1.5).round(),
                    (truth.apex_px[1] - 1.0).round(),
                ];
                let end = truth.edge(kind.apex_edges()[1]).unwrap();
                let mut automatic = [None, None];
                for (way, apex) in [Some(near), None].into_iter().enumerate() {
                    let Ok((found, template)) = auto_calibrate_rigid(&reference, apex) else {
                        refused[way] += 1;
                        continue;
                    };
                    assert_eq!(
                        found.edges.len(),
                        3,
                        "{} seed {seed}: {:?}",
                        kind.name(),
                        found.edges
                    );
                    if apex.is_none() {
                        let off =
                            |q: [f64; 2]| (template.apex[0] - q[0]).hypot(template.apex[1] - q[1]);
                        assert!(
                            off(end.from).min(off(end.to)) < 1.0,
                            "{} seed {seed}: tip point {:?} is no corner of the end {end:?}",
                            kind.name(),
                            template.apex
                        );
                    }
                    automatic[way] = Some(lab_tracker(template));
                }
                let clicks = clicks_of(&session);
                let mut hand =
                    lab_tracker(calibrate_rigid(&reference, &clicks, session.apex).unwrap());
                for spec in &session.frames {
                    let truth = render_tool_into(spec, &crops, &mut frame);
                    if !truth.in_view {
                        continue;
                    }
                    let clicked = hand.track(&frame);
                    for (tracker, (with_clicks, with_auto)) in
                        automatic.iter_mut().zip(&mut measured)
                    {
                        let Some(tracker) = tracker else {
                            continue;
                        };
                        for (m, e) in [(with_clicks, clicked), (with_auto, tracker.track(&frame))] {
                            m.in_view += 1;
                            if e.detected {
                                m.detected += 1;
                                m.errors
                                    .push((e.angle_deg.unwrap() - truth.angle_deg).abs());
                            }
                        }
                    }
                }
            }
            for (way, (clicked, automatic)) in ["from a pixel", "from none"].iter().zip(&measured) {
                let (median, p95) = (
                    quantile(&automatic.errors, 0.5),
                    quantile(&automatic.errors, 0.95),
                );
                let clicked_p95 = quantile(&clicked.errors, 0.95);
                println!(
                    "{} seed {seed}, {way}: clicked {} of {}, automatic {} of {}, median \
                     {median:.4} p95 {p95:.4} deg (clicked {clicked_p95:.4})",
                    kind.name(),
                    clicked.detected,
                    clicked.in_view,
                    automatic.detected,
                    automatic.in_view
                );
                assert!(
                    automatic.detected as f64 >= 0.98 * clicked.detected as f64,
                    "{} seed {seed}, {way}: {} detected, {} with clicks",
                    kind.name(),
                    automatic.detected,
                    clicked.detected
                );
                assert!(
                    median <= 0.03 && p95 <= 0.10,
                    "{} seed {seed}, {way}",
                    kind.name()
                );
            }
        }
    }
    assert!(
        refused[0] <= 2,
        "{} of 96 references refused from the pixel",
        refused[0]
    );
    assert!(
        refused[1] <= 8,
        "{} of 96 references refused from none",
        refused[1]
    );
}
