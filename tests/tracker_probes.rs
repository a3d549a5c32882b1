//! Several probes in one view (`vision::ProbeSet`): rendered sessions of two probes
//! facing each other at 640x480 and of four at 1024x768 (`Session::several`), every
//! probe calibrated on the shared reference from its own clicks and tracked in every
//! frame. Each probe is scored against its own truth, as `replay` writes its own CSV:
//! detection, no detection while it is out of view (the other probes still in it), no
//! tip placed on another probe, and the rendered suite's accuracy. One set pairs an AFM
//! cantilever with a rigid tool (a needle, a tipless lever, a gripper jaw), another
//! two rigid tools.
//!
//! The seeds are generated; `PROBES_SEED=n` runs another (the thresholds were set on 3,
//! 5 and 8 and checked on the held-out 11). Run with `cargo test --release --test
//! tracker_probes`.
mod tracker_support;

use image::GrayImage;
use nanoforce::scene::{
    render_into, render_tool_into, tool_truth, truth_of, FrameFormat, FrameSpec, Session, ToolKind,
};
use nanoforce::session::results::read_results;
use nanoforce::vision::{Estimate, Miss, ProbeSet, Tracker};
use tracker_support::{rendered, score, Truth, MISPLACED_PX};

fn seed(default: u64) -> u64 {
    std::env::var("PROBES_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Every probe of `session` calibrated on its reference from its own clicks, without
/// coherence (the frames are in random order).
fn trackers(session: &Session) -> Vec<Tracker> {
    let mut trackers = session
        .trackers()
        .expect("the rendered reference calibrates");
    trackers.iter_mut().for_each(|t| t.set_coherence(false));
    trackers
}

/// Renders and tracks every frame; per probe, its truth and estimates.
fn run(session: &Session) -> Vec<(Vec<Truth>, Vec<Estimate>)> {
    let probes = session.reference.probe_count();
    let mut set = ProbeSet::new(trackers(session), &vec![0; session.reference.probe_count()]);
    let mut per_probe = vec![(Vec::new(), Vec::new()); probes];
    let mut frame = GrayImage::new(1, 1);
    let mut estimates = vec![Estimate::default(); probes];
    for (i, spec) in session.frames.iter().enumerate() {
        render_into(spec, &mut frame);
        set.track(&frame, &mut estimates);
        for (k, (truths, found)) in per_probe.iter_mut().enumerate() {
            let t = truth_of(&spec.nth_probe(k).expect("placed"));
            truths.push(rendered::truth(i, spec, &t));
            found.push(estimates[k]);
        }
    }
    per_probe
}

/// Checks each probe's score: detection, no detection while it is out of view, no true
/// tip refused as another probe's or for its scale (the bodies are apart, the
/// magnification one), and its accuracy. The probes are
/// 45-260 px tall (1000x-2000x: each must keep to its part of the view), smaller than
/// the single-probe suite's, and the misses are the single-probe tracker's (harsh and
/// noisy frames refused by the scale checks): `each_probe_tracks_as_it_would_alone`
/// shows the other probes cost next to nothing. Measured per probe on seeds 3, 5, 8
/// and 11: detection 97.8-100 %, angle median 0.0095-0.0225 deg, p95 0.055-0.128 deg.
fn check(name: &str, per_probe: &[(Vec<Truth>, Vec<Estimate>)]) {
    for (k, (t, e)) in per_probe.iter().enumerate() {
        let sc = score(t, e);
        let why = format!("{name}, probe {}: {sc:?}", k + 1);
        println!("{why}");
        let others = t
            .iter()
            .zip(e)
            .filter(|(t, e)| {
                t.detected && matches!(e.miss, Some(Miss::OtherProbe | Miss::ScaleUnlikeOthers))
            })
            .count();
        assert!(sc.detect_rate >= 0.975, "{why}");
        assert_eq!(sc.false_detections, 0, "{why}");
        assert!(sc.angle_err_median_deg <= 0.025, "{why}");
        assert!(sc.angle_err_p95_deg <= 0.13, "{why}");
        assert!(sc.tip_err_median_px <= 0.2, "{why}");
        assert_eq!(others, 0, "{why}: refused as another probe's body or scale");
    }
}

#[test]
fn two_probes_facing_each_other_are_each_tracked() {
    let session = Session::several(seed(3), 2, 300, 640, 480);
    let per_probe = run(&session);
    let blank: usize = per_probe
        .iter()
        .map(|(t, _)| t.iter().filter(|t| !t.detected).count())
        .sum();
    assert!(blank > 10, "the session puts probes out of view: {blank}");
    check("two probes", &per_probe);
}

#[test]
fn each_probe_tracks_as_it_would_alone() {
    // The same frames with only probe k drawn: the other probe in view costs it no
    // accuracy and at most one frame in a hundred.
    let session = Session::several(seed(3), 2, 300, 640, 480);
    let together = run(&session);
    for (k, (t, e)) in together.iter().enumerate() {
        // Every other probe out of view; the rest of the frame (its substrate, clutter
        // and noise) as it was.
        let mut alone = session.clone();
        for frame in &mut alone.frames {
            frame.blank |= k != 0;
            for (j, other) in frame.others.iter_mut().enumerate() {
                other.blank |= j + 1 != k;
            }
        }
        let mut tracker = trackers(&session).swap_remove(k);
        let mut frame = GrayImage::new(1, 1);
        let found: Vec<Estimate> = alone
            .frames
            .iter()
            .map(|spec| {
                render_into(spec, &mut frame);
                tracker.track(&frame)
            })
            .collect();
        let (with, without) = (score(t, e), score(t, &found));
        let why = format!(
            "probe {}: with the other {with:?}\nalone {without:?}",
            k + 1
        );
        // The other probe moves the frame's Otsu threshold a little: on harsh frames a
        // face can lose its edge pixels (seed 8: 2 of 284 frames).
        assert!(with.detect_rate >= without.detect_rate - 0.01, "{why}");
        assert!(
            with.angle_err_median_deg <= 1.1 * without.angle_err_median_deg,
            "{why}"
        );
        assert!(
            with.angle_err_p95_deg <= 1.1 * without.angle_err_p95_deg,
            "{why}"
        );
    }
}

#[test]
fn four_probes_in_one_view_are_each_tracked() {
    let session = Session::several(seed(3), 4, 100, 1024, 768);
    check("four probes", &run(&session));
}

#[test]
fn a_probe_set_tracks_each_probe_as_its_tracker_does() {
    // Sharing the detection stages changes nothing: each probe of a set gives what
    // its tracker alone gives on the same frame.
    let session = Session::several(seed(3), 2, 40, 640, 480);
    let mut set = ProbeSet::new(trackers(&session), &[0, 0]);
    let mut alone = trackers(&session);
    let mut frame = GrayImage::new(1, 1);
    let mut estimates = vec![Estimate::default(); 2];
    for spec in &session.frames {
        render_into(spec, &mut frame);
        set.track(&frame, &mut estimates);
        for (k, tracker) in alone.iter_mut().enumerate() {
            assert_eq!(estimates[k], tracker.track(&frame), "probe {}", k + 1);
        }
    }
}

#[test]
fn a_probe_set_on_two_threads_gives_what_it_gives_on_one() {
    // Four probes (two per thread) and two (one each), conflicts between them included.
    for (count, width, height) in [(4, 1024, 768), (2, 640, 480)] {
        let session = Session::several(seed(3), count, 40, width, height);
        let groups = vec![0; count];
        let mut one = ProbeSet::new(trackers(&session), &groups);
        let mut two = ProbeSet::new(trackers(&session), &groups)
            .on_two_threads()
            .expect("a second thread starts");
        let mut frame = GrayImage::new(1, 1);
        let (mut a, mut b) = (
            vec![Estimate::default(); count],
            vec![Estimate::default(); count],
        );
        for (i, spec) in session.frames.iter().enumerate() {
            render_into(spec, &mut frame);
            one.track(&frame, &mut a);
            two.track(&frame, &mut b);
            assert_eq!(a, b, "{count} probes, frame {i}");
        }
    }
}

/// `Session::tool_beside_a_cantilever`'s 300 frames and its two trackers (the tool's
/// and the cantilever's, calibrated on the shared reference), without coherence.
fn beside_a_cantilever(kind: ToolKind, seed: u64) -> (Session, Vec<Tracker>) {
    let session = Session::tool_beside_a_cantilever(kind, seed, 300);
    let trackers = trackers(&session);
    (session, trackers)
}

/// The frames (by index) whose detection lies more than [`MISPLACED_PX`] from the
/// truth's tip.
fn misplaced(truths: &[Truth], found: &[Estimate]) -> Vec<usize> {
    let off = |t: &Truth, e: &Estimate| {
        e.apex_px
            .is_none_or(|a| (a[0] - t.tip[0]).hypot(a[1] - t.tip[1]) > MISPLACED_PX)
    };
    (0..truths.len())
        .filter(|&i| truths[i].detected && found[i].detected && off(&truths[i], &found[i]))
        .collect()
}

/// The tool's truth in `spec`, as the scores take it.
fn tool_truth_of(i: usize, spec: &FrameSpec) -> Truth {
    let t = tool_truth(spec).expect("the frame has a tool");
    Truth {
        frame: format!("frame_{i:05}"),
        detected: t.in_view,
        angle_deg: t.angle_deg,
        force_nn: f64::NAN,
        tip: t.apex_px,
        magnification: spec.magnification,
        style: spec.look.style_name.to_string(),
    }
}

#[test]
fn a_cantilever_beside_a_rigid_tool_is_tracked_with_it() {
    // A lab puts a needle, a gripper or a tipless lever beside the force-sensing
    // cantilever. Each is tracked as a probe of one set; neither is found while out
    // of view (the other still in it), and the cantilever costs the tool at most a
    // few frames against the same frames without it. The bounds were set on seeds 3,
    // 5 and 8 and checked on the held-out 11 (docs/tracker.md, "Several probes in one
    // view").
    for kind in ToolKind::ALL {
        let (session, pair) = beside_a_cantilever(kind, seed(3));
        let mut set = ProbeSet::new(pair, &[0, 0]);
        let mut alone = trackers(&session).swap_remove(0);
        let mut frame = GrayImage::new(1, 1);
        let mut estimates = vec![Estimate::default(); 2];
        let (mut truths, mut found) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
        let mut found_alone = Vec::new();
        for (i, spec) in session.frames.iter().enumerate() {
            render_tool_into(spec, &[], &mut frame);
            set.track(&frame, &mut estimates);
            let afm = truth_of(&spec.nth_probe(1).expect("placed"));
            truths[0].push(tool_truth_of(i, spec));
            truths[1].push(rendered::truth(i, spec, &afm));
            for k in 0..2 {
                found[k].push(estimates[k]);
            }
            // The same frame with the cantilever out of view.
            let mut without = *spec;
            without.others.iter_mut().for_each(|o| o.blank = true);
            render_tool_into(&without, &[], &mut frame);
            found_alone.push(alone.track(&frame));
        }
        let (tool, afm) = (score(&truths[0], &found[0]), score(&truths[1], &found[1]));
        let tool_alone = score(&truths[0], &found_alone);
        let off = misplaced(&truths[0], &found[0]);
        let why = format!(
            "{}: tool {tool:?}\nalone {tool_alone:?}\ncantilever {afm:?}\nmisplaced {off:?}",
            kind.name()
        );
        println!("{why}");
        assert!(
            tool.positives > 150 && tool.frames - tool.positives > 50,
            "{why}"
        );
        assert_eq!(tool.false_detections, 0, "{why}");
        assert!(off.is_empty(), "{why}");
        assert_eq!(afm.false_detections, 0, "{why}");
        assert!(tool.detect_rate >= tool_alone.detect_rate - 0.025, "{why}");
        assert!(tool.detect_rate >= 0.93, "{why}");
        assert!(tool.angle_err_median_deg <= 0.035, "{why}");
        assert!(afm.detect_rate >= 0.975, "{why}");
        assert!(afm.angle_err_median_deg <= 0.025, "{why}");
        assert!(afm.angle_err_p95_deg <= 0.13, "{why}");
    }
}

#[test]
fn two_rigid_tools_are_tracked_in_one_view() {
    // A needle and a gripper jaw, a jaw and a tipless lever, a lever and a needle:
    // each tool is tracked as a probe of one set, neither is found while out of view
    // (the other still in it), and each loses at most 1 % of its frames against the
    // same frames with the other out of view. The bounds were set on seeds 3, 5 and 8
    // (at most one frame lost, 97.2 % the least detected) and checked on the
    // held-out 11 (docs/tracker.md, "Several probes in one view").
    let pairs = [
        [ToolKind::Needle, ToolKind::Gripper],
        [ToolKind::Gripper, ToolKind::Tipless],
        [ToolKind::Tipless, ToolKind::Needle],
    ];
    for kinds in pairs {
        let session = Session::two_tools(kinds, seed(3), 300);
        let mut set = ProbeSet::new(trackers(&session), &[0, 0]);
        let mut alone = trackers(&session);
        let mut frame = GrayImage::new(1, 1);
        let mut estimates = vec![Estimate::default(); 2];
        let mut truths = [Vec::new(), Vec::new()];
        let mut found = [Vec::new(), Vec::new()];
        let mut found_alone = [Vec::new(), Vec::new()];
        for (i, spec) in session.frames.iter().enumerate() {
            render_tool_into(spec, &[], &mut frame);
            set.track(&frame, &mut estimates);
            for k in 0..2 {
                truths[k].push(tool_truth_of(i, &spec.nth_probe(k).expect("placed")));
                found[k].push(estimates[k]);
                // The same frame with only this tool in view.
                let mut only = *spec;
                if k == 0 {
                    only.others.iter_mut().for_each(|o| o.blank = true);
                } else {
                    only.blank = true;
                }
                render_into(&only, &mut frame);
                found_alone[k].push(alone[k].track(&frame));
            }
        }
        for k in 0..2 {
            let (both, lone) = (
                score(&truths[k], &found[k]),
                score(&truths[k], &found_alone[k]),
            );
            let why = format!(
                "{} beside {}: {both:?}\nalone {lone:?}",
                kinds[k].name(),
                kinds[1 - k].name()
            );
            println!("{why}");
            assert!(
                both.positives > 150 && both.frames - both.positives > 50,
                "{why}"
            );
            assert_eq!(both.false_detections, 0, "{why}");
            assert!(both.detect_rate >= lone.detect_rate - 0.01, "{why}");
            assert!(both.detect_rate >= 0.95, "{why}");
            assert!(both.angle_err_median_deg <= 0.035, "{why}");
        }
    }
}

#[test]
fn a_probe_refused_beside_a_found_one_is_searched_again_without_its_body() {
    // Seed 5's faint tipless lever beside a high-contrast cantilever: on some frames
    // the beam's placements fill the lever's whole shortlist, and its tracker alone
    // refuses them all. In a set the cantilever is found, and the lever's tracker
    // searches again with that body ruled out.
    let (session, pair) = beside_a_cantilever(ToolKind::Tipless, 5);
    let mut set = ProbeSet::new(pair, &[0, 0]);
    let mut lone = trackers(&session).swap_remove(0);
    let mut frame = GrayImage::new(1, 1);
    let mut estimates = vec![Estimate::default(); 2];
    let (mut in_set, mut alone, mut regained) = (0, 0, 0);
    for spec in &session.frames {
        let truth = render_tool_into(spec, &[], &mut frame);
        set.track(&frame, &mut estimates);
        let e = lone.track(&frame);
        if !truth.in_view {
            assert!(!estimates[0].detected && !e.detected, "{spec:?}");
            continue;
        }
        in_set += usize::from(estimates[0].detected);
        alone += usize::from(e.detected);
        regained += usize::from(estimates[0].detected && !e.detected);
    }
    println!(
        "lever detected in the set {in_set}, by its tracker alone {alone}, regained {regained}"
    );
    // 205 in the set, 204 alone: the frame the beam's placements take whole is
    // regained, and no frame the tracker finds alone is lost.
    assert!(
        regained >= 1 && in_set >= alone,
        "in the set {in_set}, alone {alone}, regained {regained}"
    );
}

#[test]
fn replay_writes_each_probe_of_a_tool_beside_a_cantilever() {
    // `replay` of the session folder `Session::write` makes of a needle (its named
    // edges, no cantilever) beside an AFM cantilever, two `[[probe]]` entries on one
    // reference: a CSV each, the needle's without force, the cantilever's with it.
    const FRAMES: usize = 24;
    let mut session = Session::tool_beside_a_cantilever(ToolKind::Needle, seed(3), 300);
    session.frames.truncate(FRAMES);
    let dir = tempfile::tempdir().unwrap();
    session.write(dir.path(), FrameFormat::Png).unwrap();
    let frames_dir = dir.path().join("frames");
    let truths: Vec<_> = session
        .frames
        .iter()
        .map(|spec| {
            let tool = tool_truth(spec).expect("the frame places a tool");
            (tool, truth_of(&spec.nth_probe(1).expect("placed")))
        })
        .collect();
    let toml = std::fs::read_to_string(dir.path().join("probe.toml")).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nanoforce"))
        .arg("replay")
        .arg(&frames_dir)
        .arg("--config")
        .arg(dir.path().join("probe.toml"))
        .arg("--csv")
        .arg(dir.path().join("out.csv"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}\n{toml}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut found = [0, 0];
    for (k, name) in ["probe1", "probe2"].iter().enumerate() {
        let rows = read_results(&dir.path().join(format!("out.{name}.csv"))).unwrap();
        assert_eq!(rows.len(), FRAMES, "{name}");
        for (row, (tool, afm)) in rows.iter().zip(&truths) {
            let (in_view, angle) = match k {
                0 => (tool.in_view, tool.angle_deg),
                _ => (afm.probe_in_view, afm.angle_deg),
            };
            if !row.detected {
                assert!(!row.miss.is_empty(), "{name}: {row:?}");
                continue;
            }
            assert!(in_view, "{name} detected out of view: {row:?}");
            found[k] += 1;
            // Each file holds its own probe's angles, within the pair's worst error
            // (the needle's, 0.44 deg on seed 3).
            let err = row.angle_deg.unwrap() - angle;
            assert!(err.abs() < 0.5, "{name}: {row:?} vs {angle}");
            // Force for the cantilever only.
            assert_eq!(row.force_nn.is_none(), k == 0, "{name}: {row:?}");
        }
    }
    let shown = |k: usize| {
        truths
            .iter()
            .filter(|(t, a)| if k == 0 { t.in_view } else { a.probe_in_view })
            .count()
    };
    println!("found {found:?} of {:?}", [shown(0), shown(1)]);
    assert!(
        found[0] + 1 >= shown(0) && found[1] + 1 >= shown(1),
        "{found:?}"
    );
}
