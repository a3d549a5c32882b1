//! Render time of synthetic SEM frames: the simulated lab draws one per frame at 60 Hz,
//! so a 640x480 frame must take well under 16 ms (target ~5 ms). `cargo bench --bench scene`.

use criterion::{criterion_group, criterion_main, Criterion};
use image::GrayImage;
use nanoforce::scene::{FrameSpec, Renderer, Style};

fn render_640x480(c: &mut Criterion) {
    let mut renderer = Renderer::new();
    let mut frame = GrayImage::new(640, 480);
    for style in Style::ALL {
        let spec = FrameSpec::new(style, 12.0, 7);
        c.bench_function(&format!("render_into 640x480 {}", style.name()), |b| {
            let mut seed = 0;
            b.iter(|| {
                seed += 1;
                renderer.render_into(&FrameSpec { seed, ..spec }, &mut frame)
            })
        });
    }
}

fn render_1280x960(c: &mut Criterion) {
    let mut renderer = Renderer::new();
    let mut frame = GrayImage::new(1280, 960);
    let spec = FrameSpec {
        width: 1280,
        height: 960,
        apex_px: [660.0, 520.0],
        ..FrameSpec::new(Style::Harsh, -12.0, 7)
    };
    c.bench_function("render_into 1280x960 harsh", |b| {
        b.iter(|| renderer.render_into(&spec, &mut frame))
    });
}

criterion_group!(benches, render_640x480, render_1280x960);
criterion_main!(benches);
