//! The tracker on the two public sample sessions, scored against their truth.
mod tracker_support;

use tracker_support::{sample, score, table};

#[test]
fn debug_samples() {
    for name in ["mixed", "sequence"] {
        let s = sample(name);
        let cal = s.calibrate();
        for e in nanoforce::vision::Edge::ALL {
            let c = cal.edge(e);
            println!(
                "{name} {e}: {:.3} (clicked {:.3}) seg {:?} contrast {:.1}",
                c.orientation_deg, c.clicked_orientation_deg, c.segment_px, c.contrast
            );
        }
        println!("apex {:?} blur {:.2}", cal.apex_px(), cal.blur_px());
        let est = s.run(false);
        println!("{}", table(&s.truth, &est));
        println!("{name}: {:?}", score(&s.truth, &est));
    }
}

#[test]
fn debug_scale() {
    for name in ["mixed", "sequence"] {
        let s = sample(name);
        let est = s.run(false);
        for (t, e) in s.truth.iter().zip(&est) {
            if let Some(sc) = e.scale {
                println!(
                    "{name} {} mag {} scale {:.4} -> ref mag {:.1}",
                    t.frame,
                    t.magnification,
                    sc,
                    t.magnification / sc
                );
            }
        }
    }
}

#[test]
#[ignore]
fn profile_loop() {
    let s = sample("mixed");
    let cal = s.calibrate();
    let mut tr = nanoforce::vision::Tracker::new(&s.config.tracker, cal, None);
    tr.set_coherence(false);
    let f = s.frame("frame_00001.png");
    let t0 = std::time::Instant::now();
    let n: u32 = std::env::var("N")
        .map(|s| s.parse().unwrap())
        .unwrap_or(300);
    for _ in 0..n {
        std::hint::black_box(tr.track(&f));
    }
    println!("per frame {:?}", t0.elapsed() / n);
}

#[test]
#[ignore]
fn debug_apex_offsets() {
    for name in ["mixed", "sequence"] {
        let s = sample(name);
        let est = s.run(false);
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for (t, e) in s.truth.iter().zip(&est) {
            if let Some(a) = e.apex_px {
                let (dx, dy) = (a[0] - t.tip[0], a[1] - t.tip[1]);
                println!(
                    "{name} {} mag {} dx {dx:+.3} dy {dy:+.3}",
                    t.frame, t.magnification
                );
                sx += dx;
                sy += dy;
                n += 1.0;
            }
        }
        println!("{name}: mean dx {:+.3} dy {:+.3}", sx / n, sy / n);
    }
}
