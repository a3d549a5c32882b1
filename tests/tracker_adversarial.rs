//! The tracker on frames that do not show the session's probe: how many it detects
//! (the goal is none).
//!
//! Six kinds of probe-less frames (docs/tracker.md, "What the tracker refuses, and
//! why"), generated from a seed for sessions of the rendered suite, each tracked by a
//! tracker calibrated on its session's reference: clutter (scratches and particles),
//! random bright and dark shapes, the session's probe mirrored left-right, probes of
//! another geometry, the probe with its tip under an occluding patch
//! (`nanoforce::scene::adversarial`), and sub-windows of real SEM frames
//! (`tests/data/real-sem`). Each tracker states the scales its session's SEM gives
//! (`tracker.scale_range`, as the suites' probe.toml would). The checked-in seeds are
//! a held-out one (2027) and a harder one (4242) measured after the checks were
//! developed on another (`ADVERSARIAL_SEED=n` runs any, unchecked;
//! `ADVERSARIAL_DUMP=dir` writes each falsely detected frame into dir). Run with
//! `cargo test --release --test tracker_adversarial -- --nocapture`.
mod tracker_support;

use std::collections::BTreeMap;

use image::GrayImage;
use nanoforce::scene::adversarial::{self, Adversary, Decoy};
use nanoforce::scene::rng::{sub_seed, Rng};
use nanoforce::scene::{self, Session};
use nanoforce::vision::{Estimate, Tracker};
use tracker_support::rendered;

/// Sessions of the suite the frames are made for, and frames per session and kind.
const SESSIONS: usize = 6;
const FRAMES_PER_KIND: usize = 30;

/// Per kind: frames, detections (with their description), largest confidence, and the
/// count of each miss reason.
#[derive(Default)]
struct Tally {
    frames: usize,
    detected: Vec<String>,
    max_confidence: f64,
    reasons: BTreeMap<String, usize>,
}

impl Tally {
    fn add(&mut self, what: String, e: &Estimate) {
        self.frames += 1;
        self.max_confidence = self.max_confidence.max(e.confidence);
        if e.detected {
            self.detected.push(format!(
                "{what}: angle {:?} apex {:?} scale {:?} conf {:.2}",
                e.angle_deg, e.apex_px, e.scale, e.confidence
            ));
        }
        let reason = e.miss.map_or("detected", |m| m.name()).to_string();
        *self.reasons.entry(reason).or_default() += 1;
    }
}

fn run(seed: u64) -> BTreeMap<&'static str, Tally> {
    let sessions = scene::suite(seed, SESSIONS, 1);
    let crops = rendered::real_crops();
    let mut adversary = Adversary::new();
    let mut frame = GrayImage::new(1, 1);
    let mut tallies: BTreeMap<&'static str, Tally> = BTreeMap::new();
    // ADVERSARIAL_DUMP=dir writes each falsely detected frame there, to look at.
    let dump = std::env::var("ADVERSARIAL_DUMP").ok();
    for (i, session) in sessions.iter().enumerate() {
        let mut tracker: Tracker = rendered::tracker(session, false);
        for decoy in Decoy::ALL {
            for k in 0..FRAMES_PER_KIND {
                let frame_seed = sub_seed(seed, (1000 * i + 100 * decoy as usize + k) as u64);
                let spec = adversary.render_into(session, decoy, frame_seed, &mut frame);
                let e = tracker.track(&frame);
                let what = format!(
                    "session {i} frame {k} ({} {}x {:.1} deg)",
                    spec.look.style_name, spec.magnification, spec.angle_deg
                );
                if let (true, Some(dir)) = (e.detected, &dump) {
                    let name = format!("{}-s{i}-f{k}.png", decoy.name());
                    nanoforce::vision::draw_overlay(&frame, &e)
                        .save(std::path::Path::new(dir).join(name))
                        .unwrap();
                }
                tallies.entry(decoy.name()).or_default().add(what, &e);
            }
        }
        let mut rng = Rng::new(sub_seed(seed, 7000 + i as u64));
        let (w, h) = (session.reference.width, session.reference.height);
        for k in 0..FRAMES_PER_KIND {
            let real = adversarial::real_window(&crops, w, h, &mut rng);
            let e = tracker.track(&real);
            tallies
                .entry("real-sem")
                .or_default()
                .add(format!("session {i} frame {k}"), &e);
        }
    }
    tallies
}

fn report(tallies: &BTreeMap<&'static str, Tally>) -> String {
    let mut out = String::new();
    for (kind, t) in tallies {
        out += &format!(
            "{kind}: {} frames, {} detected, largest confidence {:.3}, {:?}\n",
            t.frames,
            t.detected.len(),
            t.max_confidence,
            t.reasons
        );
        for d in &t.detected {
            out += &format!("  {d}\n");
        }
    }
    out
}

/// False detections per kind measured on the held-out seed 2027 (1080 frames) with the
/// per-edge checks (docs/tracker.md, "What the tracker refuses, and why"). The goal is
/// none on any kind; what remains is one random shape.
/// These bounds catch a regression, and a kind that reaches zero stays there.
const MEASURED: [(&str, usize); 6] = [
    ("clutter", 0),
    ("mirrored", 0),
    ("occluded", 0),
    ("other-probe", 0),
    ("real-sem", 0),
    ("shapes", 1),
];

/// The same on seed 4242 (1 of 1080 frames detected, of another kind than on 2027):
/// the held-out seed alone would let a regression on the kinds it rarely draws go
/// unseen.
const MEASURED_4242: [(&str, usize); 6] = [
    ("clutter", 0),
    ("mirrored", 0),
    ("occluded", 1),
    ("other-probe", 0),
    ("real-sem", 0),
    ("shapes", 0),
];

/// Runs the suite of `seed` and checks it against `bounds` (none when `None`).
fn check(seed: u64, bounds: Option<&[(&str, usize)]>) {
    let tallies = run(seed);
    let why = report(&tallies);
    println!("seed {seed}\n{why}");
    let frames: usize = tallies.values().map(|t| t.frames).sum();
    assert!(frames >= 1000, "{frames} frames");
    assert_eq!(tallies.len(), Decoy::ALL.len() + 1, "{why}");
    for &(kind, bound) in bounds.unwrap_or_default() {
        let found = tallies.get(kind).map_or(usize::MAX, |t| t.detected.len());
        assert!(
            found <= bound,
            "seed {seed}, {kind}: {found} > {bound}\n{why}"
        );
    }
}

#[test]
fn false_detections_without_the_probe_stay_within_the_measured_bounds() {
    match std::env::var("ADVERSARIAL_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
    {
        Some(seed) => check(seed, None),
        None => check(2027, Some(&MEASURED)),
    }
}

#[test]
fn false_detections_on_a_harder_seed_stay_within_the_measured_bounds() {
    check(4242, Some(&MEASURED_4242));
}

#[test]
fn the_decoys_are_probe_like() {
    // The generator does what it says: a mirrored frame is the probe's frame flipped,
    // and frames differ from seed to seed but not from run to run.
    let session: Session = scene::suite(5, 1, 1).remove(0);
    let mut adversary = Adversary::new();
    let (mut a, mut b) = (GrayImage::new(1, 1), GrayImage::new(1, 1));
    for decoy in Decoy::ALL {
        adversary.render_into(&session, decoy, 11, &mut a);
        adversary.render_into(&session, decoy, 11, &mut b);
        assert_eq!(a, b, "{}", decoy.name());
        adversary.render_into(&session, decoy, 12, &mut b);
        assert_ne!(a, b, "{}", decoy.name());
    }
    let spec = adversary.render_into(&session, Decoy::Mirrored, 3, &mut a);
    let (mut probe, _) = scene::render(&spec);
    image::imageops::flip_horizontal_in_place(&mut probe);
    assert_eq!(a, probe);
    // A mirrored or other probe shows its whole tip (the wedge alone, mirrored, is the
    // probe's wedge turned): apex, pyramid base and the beam's free end in the frame.
    let mut outline = Vec::new();
    for decoy in [Decoy::Mirrored, Decoy::OtherProbe] {
        for seed in 0..20 {
            let spec = adversary.render_into(&session, decoy, seed, &mut a);
            assert!(
                adversarial::shows_whole_tip(&spec, &mut outline),
                "{} seed {seed}",
                decoy.name()
            );
        }
    }
}
