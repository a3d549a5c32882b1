//! Pictures of frames the tracker refuses, for docs/tracker.md ("What the tracker
//! refuses, and why"): docs/images/refused-<kind>.png for a mirrored probe, a probe of
//! another geometry, the probe with its tip hidden, and clutter without a probe.
//!
//! Each picture is one adversarial frame (`nanoforce::scene::adversarial`, as in
//! tests/tracker_adversarial.rs), scaled to half size, with the tracker's overlay (the
//! edges and apex its estimate carries, in red, blue and green) and a caption naming
//! the decoy and the `miss` reason. The session, and from it every
//! frame, follows from `--seed`; for each kind the first frame (frame seeds 0, 1, ...)
//! the tracker refuses is drawn, so re-running after a change of the tracker's checks
//! shows what it refuses then:
//!
//! ```text
//! cargo run --release --example refused
//! cargo run --release --example refused -- --seed 5 --out docs/images
//! ```
#[path = "../tests/tracker_support/mod.rs"]
mod tracker_support;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use image::{imageops, GrayImage, Rgb, RgbImage};
use nanoforce::report::plot;
use nanoforce::scene;
use nanoforce::scene::adversarial::{Adversary, Decoy};
use nanoforce::scene::rng::sub_seed;
use nanoforce::vision::{draw_overlay, Estimate};
use tracker_support::rendered;

/// The kinds drawn, with the file name and the caption's words.
const KINDS: [(Decoy, &str, &str); 4] = [
    (Decoy::Mirrored, "mirrored", "the probe mirrored left-right"),
    (
        Decoy::OtherProbe,
        "other-probe",
        "a probe of another geometry",
    ),
    (Decoy::Occluded, "hidden-tip", "the probe, its tip hidden"),
    (Decoy::Clutter, "clutter", "clutter, no probe"),
];

/// Width of a picture (the whole frame, scaled down); height of its caption strip.
const WIDTH_PX: u32 = 320;
const CAPTION_PX: u32 = 36;

/// Frame seeds tried per kind before giving up (every one detected).
const TRIES: u64 = 200;

/// `frame` scaled to [`WIDTH_PX`] wide with the overlay of `e` (its pixels scaled
/// alike), and a white strip below it holding the caption's two lines.
fn picture(frame: &GrayImage, e: &Estimate, lines: [&str; 2]) -> RgbImage {
    let (w, h) = frame.dimensions();
    let k = f64::from(WIDTH_PX) / f64::from(w);
    let height = (f64::from(h) * k).round() as u32;
    let small = imageops::resize(frame, WIDTH_PX, height, imageops::FilterType::Triangle);
    // Pixel centres at integers: a point x maps to (x + 0.5) k - 0.5.
    let scale = |p: [f64; 2]| p.map(|v| (v + 0.5) * k - 0.5);
    let mut scaled = *e;
    scaled.apex_px = e.apex_px.map(scale);
    for fit in scaled.edges.iter_mut().flatten() {
        fit.start_px = scale(fit.start_px);
        fit.end_px = scale(fit.end_px);
    }
    let mut out = RgbImage::from_pixel(WIDTH_PX, height + CAPTION_PX, Rgb([255, 255, 255]));
    imageops::replace(&mut out, &draw_overlay(&small, &scaled), 0, 0);
    for (k, line) in lines.iter().enumerate() {
        plot::small_text(&mut out, 5, (height + 2 + 16 * k as u32) as i32, line);
    }
    out
}

/// Writes `img` as an 8-bit palette PNG: its grey pixels at full resolution (256
/// levels would need every entry, so the greys share 240, 1.1 levels apart) and up to
/// 16 other colours (the overlay's) exactly; a third of the size of RGB.
fn save_indexed(img: &RgbImage, path: &Path) -> Result<(), String> {
    const GREYS: usize = 240;
    let mut colours: Vec<Rgb<u8>> = Vec::new();
    let mut indices = Vec::with_capacity((img.width() * img.height()) as usize);
    for &p in img.pixels() {
        let [r, g, b] = p.0;
        let index = if r == g && g == b {
            (usize::from(r) * (GREYS - 1) + 127) / 255
        } else {
            let slot = colours.iter().position(|&c| c == p).unwrap_or_else(|| {
                colours.push(p);
                colours.len() - 1
            });
            GREYS + slot.min(255 - GREYS)
        };
        indices.push(index as u8);
    }
    let mut palette = Vec::with_capacity(3 * 256);
    for i in 0..GREYS {
        let level = ((i * 255 + (GREYS - 1) / 2) / (GREYS - 1)) as u8;
        palette.extend([level; 3]);
    }
    for c in colours.iter().take(256 - GREYS) {
        palette.extend(c.0);
    }
    let file = std::fs::File::create(path).map_err(|e| e.to_string())?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), img.width(), img.height());
    encoder.set_color(png::ColorType::Indexed);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_palette(palette);
    encoder.set_compression(png::Compression::High);
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(&indices).map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    let mut seed = 5u64;
    let mut out_dir = PathBuf::from("docs/images");
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let value = args.next().unwrap_or_default();
        match arg.as_str() {
            "--seed" => match value.parse() {
                Ok(n) => seed = n,
                Err(_) => {
                    eprintln!("--seed needs a whole number, got {value:?}");
                    return ExitCode::FAILURE;
                }
            },
            "--out" => out_dir = PathBuf::from(value),
            _ => {
                eprintln!("unknown argument {arg:?} (--seed N --out DIR)");
                return ExitCode::FAILURE;
            }
        }
    }
    // The suite's first session: 640x480, its own probe, look and calibration.
    let session = scene::suite(seed, 1, 1).remove(0);
    let mut tracker = rendered::tracker(&session, false);
    let mut adversary = Adversary::new();
    let mut frame = GrayImage::new(1, 1);
    let mut failed = false;
    for (decoy, file, words) in KINDS {
        let refused = (0..TRIES).find_map(|k| {
            let frame_seed = sub_seed(seed, 100 * decoy as u64 + k);
            let spec = adversary.render_into(&session, decoy, frame_seed, &mut frame);
            let e = tracker.track(&frame);
            (!e.detected).then_some((k, spec, e))
        });
        let Some((k, spec, e)) = refused else {
            eprintln!("{file}: the tracker detected all {TRIES} frames tried");
            failed = true;
            continue;
        };
        let miss = e.miss.map_or("none", |m| m.name());
        let verdict = format!("refused: {miss} (confidence {:.2})", e.confidence);
        let picture = picture(&frame, &e, [words, &verdict]);
        let path = out_dir.join(format!("refused-{file}.png"));
        if let Err(err) = save_indexed(&picture, &path) {
            eprintln!("{}: cannot write: {err}", path.display());
            return ExitCode::FAILURE;
        }
        let bytes = std::fs::metadata(&path).map_or(0, |m| m.len());
        println!(
            "{}: frame seed index {k}, {} {}x, {miss}, {} kB",
            path.display(),
            spec.look.style_name,
            spec.magnification,
            bytes / 1000
        );
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
