//! Measures the two ways a live session could keep its frames: one file of raw frames
//! behind the pipe protocol's 32-byte header, or an 8-bit PNG per frame (fast and
//! default compression). Frames: the built-in simulated lab's SEM (640 x 480, "noisy")
//! and the real SEM crops of tests/data/real-sem. Prints bytes per frame and the
//! writer's CPU time per frame; docs/operations.md quotes the numbers.
//!
//! ```text
//! cargo run --release --example frame_storage
//! ```
use std::io::Write;
use std::path::Path;
use std::time::Instant;

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{GrayImage, ImageEncoder};
use nalgebra::Vector3;
use nanoforce::cli::run::SIM_CONFIG;
use nanoforce::config::Config;
use nanoforce::hw::frames::pipe::FrameHeader;
use nanoforce::scene::Renderer;
use nanoforce::session::frames::load_gray;
use nanoforce::sim::contact::Contact;
use nanoforce::sim::sem::SemScene;

fn main() -> anyhow::Result<()> {
    let config = Config::from_toml_str(SIM_CONFIG, Path::new("sim.toml"))?;
    let contact = Contact {
        sample: config.sim.sample.clone(),
        cantilever: config.probes[0].cantilever.unwrap(),
        press_direction: config.teleop.press_direction_stage,
    };
    let scene = SemScene::new(
        config.sim.sem.clone(),
        contact,
        config.teleop.pressing_force_sign,
    );
    let mut renderer = Renderer::new();
    let sim: Vec<GrayImage> = (0..60u32)
        .map(|i| {
            let t_s = f64::from(i) / 60.0 * 30.0;
            let (spec, _) = scene.frame(t_s, i.into(), Vector3::new(0.0, 0.0, -18.0));
            let mut frame = GrayImage::new(0, 0);
            renderer.render_into(&spec, &mut frame);
            frame
        })
        .collect();
    let real_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real-sem");
    let mut real = Vec::new();
    for entry in std::fs::read_dir(&real_dir)? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "png") {
            real.push(load_gray(&path)?);
        }
    }
    for (name, frames) in [
        ("simulated SEM 640x480 noisy", &sim),
        ("real SEM crops", &real),
    ] {
        report(name, frames)?;
    }
    Ok(())
}

fn report(name: &str, frames: &[GrayImage]) -> anyhow::Result<()> {
    let pixels: usize = frames.iter().map(|f| f.as_raw().len()).sum();
    println!(
        "{name}: {} frames, {:.0} pixels each on average",
        frames.len(),
        pixels as f64 / frames.len() as f64
    );
    let dir = tempfile::tempdir()?;
    // Raw, one file, header + pixels.
    let started = Instant::now();
    let path = dir.path().join("frames.nfrm");
    let mut out = std::io::BufWriter::new(std::fs::File::create(&path)?);
    for (i, f) in frames.iter().enumerate() {
        let header = FrameHeader {
            width: f.width(),
            height: f.height(),
            sequence: i as u64,
            capture_ns: 1,
        };
        out.write_all(&header.encode())?;
        out.write_all(f.as_raw())?;
    }
    out.into_inner()?.sync_all()?;
    let raw_ms = started.elapsed().as_secs_f64() * 1e3 / frames.len() as f64;
    let raw_bytes = std::fs::metadata(&path)?.len() as f64 / frames.len() as f64;
    println!(
        "  raw + header  {:>9.0} B/frame  ({:.3} of the pixels)  {raw_ms:.3} ms/frame",
        raw_bytes,
        raw_bytes * frames.len() as f64 / pixels as f64
    );
    for (label, compression) in [
        ("png fast", CompressionType::Fast),
        ("png default", CompressionType::Default),
        ("png best", CompressionType::Best),
    ] {
        let started = Instant::now();
        let mut bytes = 0usize;
        for (i, f) in frames.iter().enumerate() {
            let path = dir.path().join(format!("{label}-{i:06}.png"));
            let mut buf = Vec::new();
            PngEncoder::new_with_quality(&mut buf, compression, FilterType::Adaptive).write_image(
                f.as_raw(),
                f.width(),
                f.height(),
                image::ExtendedColorType::L8,
            )?;
            bytes += buf.len();
            std::fs::write(&path, &buf)?;
        }
        let ms = started.elapsed().as_secs_f64() * 1e3 / frames.len() as f64;
        let per = bytes as f64 / frames.len() as f64;
        println!(
            "  {label:<12}  {per:>9.0} B/frame  ({:.3} of the pixels)  {ms:.3} ms/frame",
            bytes as f64 / pixels as f64
        );
    }
    Ok(())
}
