//! The tracker on rendered sessions with exact truth (`nanoforce::scene`).
mod tracker_support;

use tracker_support::{percentile, rendered, score, table};

#[test]
#[ignore]
fn debug_suite() {
    let n_sessions: usize = std::env::var("SESSIONS")
        .map(|s| s.parse().unwrap())
        .unwrap_or(12);
    let per: usize = std::env::var("PER")
        .map(|s| s.parse().unwrap())
        .unwrap_or(50);
    let seed: u64 = std::env::var("SEED")
        .map(|s| s.parse().unwrap())
        .unwrap_or(2024);
    let sessions = nanoforce::scene::suite(seed, n_sessions, per);
    let mut all_t = Vec::new();
    let mut all_e = Vec::new();
    for (i, s) in sessions.iter().enumerate() {
        let (t, e) = rendered::run(s, false);
        let sc = score(&t, &e);
        println!(
            "session {i} ({}x{}, {:?}, base {:.1}): {sc:?}",
            s.reference.width, s.reference.height, s.reference.entry, s.reference.base_deg
        );
        if std::env::var("TABLE").is_ok() {
            println!("{}", table(&t, &e));
        }
        all_t.extend(t);
        all_e.extend(e);
    }
    println!("ALL: {:?}", score(&all_t, &all_e));
    for style in ["clean", "clutter", "noisy", "harsh"] {
        let idx: Vec<usize> = (0..all_t.len())
            .filter(|&i| all_t[i].style == style)
            .collect();
        let t: Vec<_> = idx.iter().map(|&i| all_t[i].clone()).collect();
        let e: Vec<_> = idx.iter().map(|&i| all_e[i]).collect();
        println!("{style}: {:?}", score(&t, &e));
    }
    for (lo, hi) in [
        (1000.0, 1500.0),
        (1500.0, 2500.0),
        (2500.0, 4000.0),
        (4000.0, 8001.0),
    ] {
        let idx: Vec<usize> = (0..all_t.len())
            .filter(|&i| all_t[i].magnification >= lo && all_t[i].magnification < hi)
            .collect();
        let t: Vec<_> = idx.iter().map(|&i| all_t[i].clone()).collect();
        let e: Vec<_> = idx.iter().map(|&i| all_e[i]).collect();
        println!("mag {lo}-{hi}: {:?}", score(&t, &e));
    }
    let mut worst: Vec<(f64, usize)> = (0..all_t.len())
        .filter(|&i| all_t[i].detected && all_e[i].detected)
        .map(|i| ((all_e[i].angle_deg.unwrap() - all_t[i].angle_deg).abs(), i))
        .collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    for &(err, i) in worst.iter().take(15) {
        println!(
            "worst {err:.3} frame #{i} session {} k {} {} mag {} angle {:.2}",
            i / per,
            i % per,
            all_t[i].style,
            all_t[i].magnification,
            all_t[i].angle_deg
        );
    }
    for i in 0..all_t.len() {
        if all_t[i].detected != all_e[i].detected {
            println!("detection mismatch #{i} session {} k {} truth {} est {} {} mag {} angle {:.2} miss {:?} conf {:.2}", i / per, i % per, all_t[i].detected, all_e[i].detected, all_t[i].style, all_t[i].magnification, all_t[i].angle_deg, all_e[i].miss, all_e[i].confidence);
        }
    }
    let _ = percentile;
}

/// Writes suite session `SESSION` to `OUT` (scene.md layout) for a closer look.
#[test]
#[ignore]
fn debug_write_session() {
    let seed: u64 = std::env::var("SEED")
        .map(|s| s.parse().unwrap())
        .unwrap_or(2024);
    let n_sessions: usize = std::env::var("SESSIONS")
        .map(|s| s.parse().unwrap())
        .unwrap_or(12);
    let per: usize = std::env::var("PER")
        .map(|s| s.parse().unwrap())
        .unwrap_or(50);
    let i: usize = std::env::var("SESSION").unwrap().parse().unwrap();
    let out = std::env::var("OUT").unwrap();
    let mut sessions = nanoforce::scene::suite(seed, n_sessions, per);
    if std::env::var("BLANK").is_ok() {
        for f in &mut sessions[i].frames {
            f.blank = true;
        }
    }
    sessions[i]
        .write(
            std::path::Path::new(&out),
            nanoforce::scene::FrameFormat::Png,
        )
        .unwrap();
}

/// Many blank frames (clutter, substrate, shading, noise; no probe): false detections
/// and the largest confidence reached.
#[test]
#[ignore]
fn debug_blank() {
    let seed: u64 = std::env::var("SEED")
        .map(|s| s.parse().unwrap())
        .unwrap_or(77);
    let n_sessions: usize = std::env::var("SESSIONS")
        .map(|s| s.parse().unwrap())
        .unwrap_or(12);
    let per: usize = std::env::var("PER")
        .map(|s| s.parse().unwrap())
        .unwrap_or(50);
    let mut sessions = nanoforce::scene::suite(seed, n_sessions, per);
    let mut false_pos = 0;
    let mut max_conf: f64 = 0.0;
    let mut misses = [0usize; 4];
    for (i, s) in sessions.iter_mut().enumerate() {
        for f in &mut s.frames {
            f.blank = true;
        }
        let (t, e) = rendered::run(s, false);
        for (k, (_, est)) in t.iter().zip(&e).enumerate() {
            max_conf = max_conf.max(est.confidence);
            if est.confidence > 0.25 {
                println!(
                    "NEAR session {i} frame {k}: conf {:.3} {:?}",
                    est.confidence, est.miss
                );
            }
            if est.detected {
                false_pos += 1;
                println!("FALSE session {i} frame {k}: {est:?}");
            }
            match est.miss {
                Some(nanoforce::vision::Miss::NoCandidates) => misses[0] += 1,
                Some(nanoforce::vision::Miss::Inconsistent) => misses[1] += 1,
                Some(nanoforce::vision::Miss::LowConfidence) => misses[2] += 1,
                None => misses[3] += 1,
            }
        }
    }
    println!("blank frames {}: false {false_pos}, max confidence {max_conf:.3}, misses (none/inconsistent/low/none) {misses:?}", n_sessions * per);
}

/// Truth edges of suite frame SESSION/FRAME.
#[test]
#[ignore]
fn debug_truth_edges() {
    let seed: u64 = std::env::var("SEED")
        .map(|s| s.parse().unwrap())
        .unwrap_or(2024);
    let i: usize = std::env::var("SESSION").unwrap().parse().unwrap();
    let k: usize = std::env::var("FRAME").unwrap().parse().unwrap();
    let sessions = nanoforce::scene::suite(seed, 12, 50);
    let (_, t) = nanoforce::scene::render(&sessions[i].frames[k]);
    let (_, r) = nanoforce::scene::render(&sessions[i].reference);
    let (e, re) = (t.edges.unwrap(), r.edges.unwrap());
    for (name, s, rs) in [
        ("red", e.red, re.red),
        ("blue", e.blue, re.blue),
        ("green", e.green, re.green),
    ] {
        println!(
            "{name}: frame {:?} angle {:.4} | reference angle {:.4} | diff {:.4}",
            s,
            s.angle_deg(),
            rs.angle_deg(),
            s.angle_deg() - rs.angle_deg()
        );
    }
    println!(
        "truth angle {:.4} probe {:?}",
        t.angle_deg,
        sessions[i].probe()
    );
}

/// A short cantilever at low magnification and large angles: a strongly bent beam.
#[test]
#[ignore]
fn debug_short_beam() {
    use nanoforce::scene::{Entry, Session, Setup, Style};
    for (entry, base) in [(Entry::Left, -10.0), (Entry::Right, 15.0)] {
        let mut setup = Setup::random(5, 640, 480);
        setup.probe.length_um = 100.0;
        setup.entry = entry;
        setup.base_deg = base;
        let mut session = Session::mixed_for(&setup, 3, 8);
        for (k, f) in session.frames.iter_mut().enumerate() {
            *f = setup.frame(
                Style::Clean,
                if k % 2 == 0 { 20.0 } else { -20.0 },
                1000.0 + 250.0 * (k / 2) as f64,
                40 + k as u64,
            );
            f.apex_px = [320.0, 240.0];
        }
        let (t, e) = rendered::run(&session, false);
        println!("{}", table(&t, &e));
    }
}
