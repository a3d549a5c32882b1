//! Tracking alone (decoded 8-bit frame in, estimate out), single thread, on the public
//! samples: a 640x480 frame as recorded and the same frame scaled to 1280x960.
//! `cargo bench --bench tracker`; docs/tracker.md records the numbers.
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use image::imageops::{resize, FilterType};
use image::GrayImage;
use nanoforce::config::Config;
use nanoforce::vision::{Calibration, Tracker};

fn session(name: &str) -> (Config, GrayImage) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/samples")
        .join(name);
    let config = Config::load(&dir.join("probe.toml")).expect("sample config");
    let cal = config.tracker.calibration.as_ref().expect("calibration");
    let reference = image::open(&cal.reference_image)
        .expect("reference")
        .to_luma8();
    (config, reference)
}

fn frame(name: &str, file: &str) -> GrayImage {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/samples")
        .join(name);
    image::open(dir.join("frames").join(file))
        .expect("frame")
        .to_luma8()
}

fn bench_tracking(c: &mut Criterion) {
    let mut group = c.benchmark_group("track");
    for (name, file) in [
        ("mixed", "frame_00001.png"),
        ("mixed", "frame_00029.png"),
        ("sequence", "frame_00012.png"),
    ] {
        let (config, reference) = session(name);
        for size in [640u32, 1280] {
            let (reference, img) = if size == 640 {
                (reference.clone(), frame(name, file))
            } else {
                // A larger sensor sees the same field: scale reference and frame alike.
                let up = |i: &GrayImage| resize(i, 1280, 960, FilterType::Triangle);
                (up(&reference), up(&frame(name, file)))
            };
            let mut clicks = config.tracker.calibration.clone().expect("calibration");
            let k = size as f64 / 640.0;
            for pts in [&mut clicks.red, &mut clicks.blue, &mut clicks.green] {
                for p in pts.iter_mut() {
                    *p = [p[0] * k + 0.5 * (k - 1.0), p[1] * k + 0.5 * (k - 1.0)];
                }
            }
            let cal = Calibration::from_reference(&reference, &clicks, &config.tracker)
                .expect("calibrates");
            let mut tracker = Tracker::new(&config.tracker, cal, Some(config.cantilever));
            tracker.set_coherence(false);
            assert!(tracker.track(&img).detected, "{name}/{file} at {size}");
            let id = BenchmarkId::new(
                format!("{name}/{file}"),
                format!("{}x{}", img.width(), img.height()),
            );
            group.bench_with_input(id, &img, |b, img| b.iter(|| tracker.track(img)));
        }
    }
    group.finish();
}

criterion_group!(benches, bench_tracking);
criterion_main!(benches);
