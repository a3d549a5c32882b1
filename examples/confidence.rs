//! What `confidence` means, measured: per confidence band of the detections, how often a
//! frame without the probe is detected and how far off the angle is when the probe is
//! there. Writes docs/images/confidence.png and prints the table of docs/tracker.md
//! ("Uncertainty and confidence").
//!
//! Two suites, both from `nanoforce::scene` and both deterministic from their seeds:
//! - the rendered suite of the tracker tests (`scene::suite(seed, 12, 50)`: 600 frames
//!   spanning every condition of docs/renderer.md, blank frames among them), each
//!   session tracked by a tracker calibrated on its own reference
//!   (tests/tracker_support);
//! - the adversarial suite of tests/tracker_adversarial.rs (`scene::adversarial`: six
//!   sessions of a rendered suite, 30 frames of each decoy kind per session, plus
//!   sub-windows of the real SEM crops in tests/data/real-sem), none showing the
//!   session's probe.
//!
//! ```text
//! cargo run --release --example confidence
//! cargo run --release --example confidence -- --rendered 31,1,2,3 --adversarial 2027,7 \
//!     --out docs/images/confidence.png
//! ```
#[path = "../tests/tracker_support/mod.rs"]
mod tracker_support;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use image::GrayImage;
use nanoforce::report::plot::{self, Panel, Series};
use nanoforce::scene::adversarial::{self, Adversary, Decoy};
use nanoforce::scene::rng::{sub_seed, Rng};
use nanoforce::scene::{self, Session};
use nanoforce::session::score::percentile;
use nanoforce::vision::Estimate;
use tracker_support::rendered;

/// Lower ends of the confidence bands a detection can fall in (the tracker reports
/// none below 0.5); each band is 0.1 wide.
const BANDS: [f64; 5] = [0.5, 0.6, 0.7, 0.8, 0.9];

/// Frames per decoy kind and session in the adversarial suite, and its sessions.
const ADVERSARIAL_SESSIONS: usize = 6;
const FRAMES_PER_KIND: usize = 30;

/// The band of a detection's confidence.
fn band(confidence: f64) -> usize {
    BANDS.iter().rposition(|&lo| confidence >= lo).unwrap_or(0)
}

/// What one band holds.
#[derive(Debug, Default, Clone)]
struct Band {
    /// |angle error| of the detections with the probe in view (rendered suite), deg.
    errors: Vec<f64>,
    /// Detections of rendered frames without the probe.
    rendered_false: usize,
    /// Detections of adversarial frames.
    adversarial_false: usize,
}

#[derive(Debug, Default)]
struct Tally {
    bands: [Band; BANDS.len()],
    rendered_probe_frames: usize,
    rendered_blank_frames: usize,
    rendered_misses: usize,
    adversarial_frames: usize,
}

impl Tally {
    fn rendered(&mut self, probe_in_view: bool, true_angle_deg: f64, e: &Estimate) {
        if probe_in_view {
            self.rendered_probe_frames += 1;
        } else {
            self.rendered_blank_frames += 1;
        }
        if !e.detected {
            self.rendered_misses += usize::from(probe_in_view);
            return;
        }
        let b = &mut self.bands[band(e.confidence)];
        match e.angle_deg {
            Some(a) if probe_in_view => b.errors.push((a - true_angle_deg).abs()),
            _ => b.rendered_false += 1,
        }
    }

    fn adversarial(&mut self, e: &Estimate) {
        self.adversarial_frames += 1;
        if e.detected {
            self.bands[band(e.confidence)].adversarial_false += 1;
        }
    }
}

/// Renders and tracks the rendered suite of `seed`.
fn rendered_suite(seed: u64, tally: &mut Tally) {
    for session in scene::suite(seed, 12, 50) {
        let (truths, estimates) = rendered::run(&session, false);
        for (t, e) in truths.iter().zip(&estimates) {
            tally.rendered(t.detected, t.angle_deg, e);
        }
    }
}

/// Renders and tracks the adversarial suite of `seed`.
fn adversarial_suite(seed: u64, crops: &[GrayImage], tally: &mut Tally) {
    let sessions: Vec<Session> = scene::suite(seed, ADVERSARIAL_SESSIONS, 1);
    let mut adversary = Adversary::new();
    let mut frame = GrayImage::new(1, 1);
    for (i, session) in sessions.iter().enumerate() {
        let mut tracker = rendered::tracker(session, false);
        for decoy in Decoy::ALL {
            for k in 0..FRAMES_PER_KIND {
                let frame_seed = sub_seed(seed, (1000 * i + 100 * decoy as usize + k) as u64);
                adversary.render_into(session, decoy, frame_seed, &mut frame);
                tally.adversarial(&tracker.track(&frame));
            }
        }
        let mut rng = Rng::new(sub_seed(seed, 7000 + i as u64));
        let (w, h) = (session.reference.width, session.reference.height);
        for _ in 0..FRAMES_PER_KIND {
            let real = adversarial::real_window(crops, w, h, &mut rng);
            tally.adversarial(&tracker.track(&real));
        }
    }
}

/// The markdown table of docs/tracker.md.
fn table(tally: &Tally) -> String {
    let mut out = format!(
        "| confidence | detections (probe in view) | angle error median (deg) | p95 (deg) | \
         max (deg) | false: rendered, of {} without the probe | false: adversarial, of {} |\n\
         |---|---|---|---|---|---|---|\n\
         | below 0.5 | not reported: {} misses of {} | | | | | |\n",
        tally.rendered_blank_frames,
        tally.adversarial_frames,
        tally.rendered_misses,
        tally.rendered_probe_frames
    );
    for (lo, b) in BANDS.iter().zip(&tally.bands) {
        let stat = |q: f64| {
            if b.errors.is_empty() {
                "-".to_string()
            } else {
                format!("{:.3}", percentile(&b.errors, q))
            }
        };
        out += &format!(
            "| {lo:.1}-{:.1} | {} | {} | {} | {} | {} | {} |\n",
            lo + 0.1,
            b.errors.len(),
            stat(50.0),
            stat(95.0),
            stat(100.0),
            b.rendered_false,
            b.adversarial_false
        );
    }
    out
}

/// The two-panel plot: false detections per 1,000 probe-less frames, and the angle
/// error's median and p95, per band.
fn picture(tally: &Tally) -> image::RgbImage {
    let centre = |k: usize| BANDS[k] + 0.05;
    let per_mille = |count: usize, of: usize| 1000.0 * count as f64 / of.max(1) as f64;
    let series = |label: &str, colour, f: &dyn Fn(&Band) -> Option<f64>| Series {
        label: label.to_string(),
        points: (0..BANDS.len())
            .filter_map(|k| f(&tally.bands[k]).map(|v| [centre(k), v]))
            .collect(),
        colour,
        style: plot::Style::LineDots,
    };
    let false_rendered = series("rendered, no probe", plot::BLUE, &|b| {
        Some(per_mille(b.rendered_false, tally.rendered_blank_frames))
    });
    let false_adversarial = series("adversarial", plot::RED, &|b| {
        Some(per_mille(b.adversarial_false, tally.adversarial_frames))
    });
    let top = false_rendered
        .points
        .iter()
        .chain(&false_adversarial.points)
        .map(|p| p[1])
        .fold(1.0, f64::max);
    let error = |q: f64| move |b: &Band| (!b.errors.is_empty()).then(|| percentile(&b.errors, q));
    let median = series("median", plot::BLUE, &error(50.0));
    let p95 = series("p95", plot::ORANGE, &error(95.0));
    let panels = [
        Panel {
            title: "False detections per 1,000 frames".into(),
            y_label: "per 1,000".into(),
            series: vec![false_rendered, false_adversarial],
            y_range: Some([0.0, 1.1 * top]),
        },
        Panel {
            title: "|angle error| when the probe is in view".into(),
            y_label: "deg".into(),
            series: vec![median, p95],
            y_range: None,
        },
    ];
    plot::panels(
        &panels,
        "confidence (band centre; bands 0.1 wide)",
        900,
        300,
    )
}

/// Comma-separated seeds.
fn seeds(text: &str) -> Option<Vec<u64>> {
    text.split(',').map(|s| s.trim().parse().ok()).collect()
}

fn main() -> ExitCode {
    let mut rendered_seeds = vec![31, 1, 2, 3];
    let mut adversarial_seeds = vec![2027, 7];
    let mut out = PathBuf::from("docs/images/confidence.png");
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let value = args.next().unwrap_or_default();
        match arg.as_str() {
            "--rendered" | "--adversarial" => {
                let Some(list) = seeds(&value) else {
                    eprintln!("{arg}: expected comma-separated whole numbers, got {value:?}");
                    return ExitCode::FAILURE;
                };
                if arg == "--rendered" {
                    rendered_seeds = list;
                } else {
                    adversarial_seeds = list;
                }
            }
            "--out" => out = PathBuf::from(value),
            _ => {
                eprintln!(
                    "unknown argument {arg:?} (--rendered S,.. --adversarial S,.. --out PNG)"
                );
                return ExitCode::FAILURE;
            }
        }
    }
    let started = Instant::now();
    let mut tally = Tally::default();
    for &seed in &rendered_seeds {
        rendered_suite(seed, &mut tally);
    }
    let crops = rendered::real_crops();
    for &seed in &adversarial_seeds {
        adversarial_suite(seed, &crops, &mut tally);
    }
    println!(
        "rendered suites {rendered_seeds:?} ({} frames with the probe, {} without), \
         adversarial suites {adversarial_seeds:?} ({} frames), {:.0} s\n",
        tally.rendered_probe_frames,
        tally.rendered_blank_frames,
        tally.adversarial_frames,
        started.elapsed().as_secs_f64()
    );
    print!("{}", table(&tally));
    if let Err(err) = picture(&tally).save(&out) {
        eprintln!("{}: cannot write: {err}", out.display());
        return ExitCode::FAILURE;
    }
    println!("\nwrote {}", out.display());
    ExitCode::SUCCESS
}
