//! The report's strip of overlay thumbnails: frames spread evenly over the session, each
//! with its found edges in red, blue and green and the apex marked (the paper's Figure 8,
//! [`crate::vision::draw_overlay`]). Of a session of several probes every probe is drawn
//! on each thumbnail, and its caption has a line per probe.
//!
//! A replayed session draws them from its frames and the edge columns of the replay CSV
//! (nothing is tracked again). A recorded session shows the thumbnails the daemon drew
//! during the run (`thumbnails/frame_<seq>.png`, off the real-time threads); a recording
//! without them has no strip, and the report says so.
//!
//! A frame name from the CSV is only ever a file name inside the frames folder: a name
//! with `..`, a folder or an absolute path (a CSV edited or written elsewhere) is skipped
//! with a warning, never followed out of the session.
use std::path::{Component, Path, PathBuf};

use image::imageops::{self, FilterType};
use image::{GrayImage, Rgb, RgbImage};

use super::load::{FrameRow, Kind, SessionData};
use super::{force_unit, plot};
use crate::session::frames::load_gray;
use crate::vision::{draw_overlays, EdgeFit, Estimate};

/// Width of one thumbnail, pixels.
pub const THUMB_WIDTH: u32 = 320;

/// Height of a caption line in the strip, pixels.
const LINE_PX: u32 = 16;

/// One picture of the strip.
#[derive(Debug, Clone)]
pub struct Thumbnail {
    pub image: RgbImage,
    /// Its lines: the frame and its tracked values (a lone probe), or the frame and a
    /// line per probe.
    pub caption: Vec<String>,
}

/// Up to `max` thumbnails, and a note when the strip is missing or incomplete.
pub fn thumbnails(data: &SessionData, max: usize) -> (Vec<Thumbnail>, Option<String>) {
    match &data.kind {
        Kind::Replayed { frames_dir, .. } => from_frames(data, frames_dir, max),
        Kind::Recorded => from_recording(data, max),
    }
}

/// `max` indices spread evenly over `0..n`, first and last included.
pub fn spread(n: usize, max: usize) -> Vec<usize> {
    match (n, max) {
        (0, _) | (_, 0) => Vec::new(),
        (n, m) if n <= m => (0..n).collect(),
        (_, 1) => vec![0],
        (n, m) => (0..m)
            .map(|i| ((i * (n - 1)) as f64 / (m - 1) as f64).round() as usize)
            .collect(),
    }
}

fn from_frames(
    data: &SessionData,
    frames_dir: &Path,
    max: usize,
) -> (Vec<Thumbnail>, Option<String>) {
    let mut out = Vec::new();
    let mut missing = 0;
    let mut outside = Vec::new();
    let frames = data.frames();
    for k in spread(frames.len(), max) {
        let row = &frames[k];
        // Skipped, not followed; the note is printed as a warning by `nanoforce report`.
        let Some(path) = frame_path(frames_dir, &row.name) else {
            outside.push(format!("{:?}", row.name));
            continue;
        };
        // Each probe's row of the frame: the k-th of its file, else the one of its name.
        let rows: Vec<Option<&FrameRow>> = data
            .probes
            .iter()
            .map(|p| {
                p.rows
                    .get(k)
                    .filter(|r| r.name == row.name)
                    .or_else(|| p.rows.iter().find(|r| r.name == row.name))
            })
            .collect();
        match load_gray(&path) {
            Ok(frame) => {
                let estimates: Vec<Estimate> =
                    rows.iter().flatten().map(|r| estimate_of(r)).collect();
                out.push(Thumbnail {
                    image: overlay_at_width(&frame, &estimates, THUMB_WIDTH),
                    caption: caption(data, row, &rows, data.timed),
                });
            }
            Err(_) => missing += 1,
        }
    }
    let mut notes = Vec::new();
    if missing > 0 {
        notes.push(format!(
            "{missing} thumbnail frame(s) could not be read from {}.",
            frames_dir.display()
        ));
    }
    if !outside.is_empty() {
        notes.push(format!(
            "{} frame name(s) of the CSV point outside the frames folder and were skipped: {}.",
            outside.len(),
            outside.join(", ")
        ));
    }
    (out, (!notes.is_empty()).then(|| notes.join(" ")))
}

/// `frames_dir/name` when `name` is a plain file name (no `..`, folder, root or prefix).
pub fn frame_path(frames_dir: &Path, name: &str) -> Option<PathBuf> {
    let mut components = Path::new(name).components();
    match (components.next(), components.next()) {
        (Some(Component::Normal(file)), None) if !name.contains(['/', '\\']) => {
            Some(frames_dir.join(file))
        }
        _ => None,
    }
}

/// The estimate a replay CSV row describes, for drawing.
fn estimate_of(row: &FrameRow) -> Estimate {
    let fit = |[a, b]: [[f64; 2]; 2]| EdgeFit {
        start_px: a,
        end_px: b,
        support: 0,
        contrast: 0.0,
    };
    Estimate {
        detected: row.detected,
        angle_deg: row.angle_deg,
        force_nn: row.force_nn,
        force_saturated: false,
        apex_px: row.tip_px,
        // The CSV holds the first three edges.
        edges: std::array::from_fn(|k| row.edges.get(k).copied().flatten().map(fit)),
        angle_sigma_deg: None,
        scale: None,
        confidence: row.confidence.unwrap_or(0.0),
        miss: None,
    }
}

fn from_recording(data: &SessionData, max: usize) -> (Vec<Thumbnail>, Option<String>) {
    let dir = data.dir.join("thumbnails");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "png"))
                .collect()
        })
        .unwrap_or_default();
    if files.is_empty() {
        let note = "this recording has no thumbnails/ (the daemon draws them when \
                    [monitor] thumbnail_every_s is above 0)";
        return (Vec::new(), Some(note.into()));
    }
    files.sort();
    let mut out = Vec::new();
    for k in spread(files.len(), max) {
        let path = &files[k];
        let Ok(image) = image::open(path) else {
            continue;
        };
        let seq = path
            .file_stem()
            .and_then(|s| s.to_str())
            .and_then(|s| s.trim_start_matches("frame_").parse::<u64>().ok());
        let rows: Vec<Option<&FrameRow>> = data
            .probes
            .iter()
            .map(|p| p.rows.iter().find(|r| seq.is_some() && r.frame_seq == seq))
            .collect();
        let caption = match rows.iter().flatten().next() {
            Some(row) => caption(data, row, &rows, true),
            None => vec![format!(
                "frame {}",
                seq.map_or("?".into(), |s| s.to_string())
            )],
        };
        out.push(Thumbnail {
            image: shrink(&image.into_rgb8()),
            caption,
        });
    }
    (out, None)
}

/// The frame shrunk to `width` (never enlarged) with every probe's estimate drawn on
/// the small picture, so the edges stay two pixels wide.
pub fn overlay_at_width(frame: &GrayImage, estimates: &[Estimate], width: u32) -> RgbImage {
    if frame.width() <= width || width == 0 {
        return draw_overlays(frame, estimates);
    }
    let k = f64::from(width) / f64::from(frame.width());
    let h = ((f64::from(frame.height()) * k).round() as u32).max(1);
    let small = imageops::resize(frame, width, h, FilterType::Triangle);
    // Pixel centres: x_small = (x + 0.5) k - 0.5.
    let map = |p: [f64; 2]| p.map(|v| (v + 0.5) * k - 0.5);
    let scaled: Vec<Estimate> = estimates
        .iter()
        .map(|estimate| {
            let mut scaled = *estimate;
            scaled.apex_px = estimate.apex_px.map(map);
            for fit in scaled.edges.iter_mut().flatten() {
                fit.start_px = map(fit.start_px);
                fit.end_px = map(fit.end_px);
            }
            scaled
        })
        .collect();
    draw_overlays(&small, &scaled)
}

fn shrink(image: &RgbImage) -> RgbImage {
    if image.width() <= THUMB_WIDTH {
        return image.clone();
    }
    let h = (u64::from(image.height()) * u64::from(THUMB_WIDTH) / u64::from(image.width())) as u32;
    imageops::resize(image, THUMB_WIDTH, h.max(1), FilterType::Triangle)
}

/// The caption of the frame of `row`: one line with its time and tracked values for a
/// lone probe; with several, the frame and its time, then each probe's values (`rows`,
/// in the probes' order) on a line of its own.
fn caption(
    data: &SessionData,
    row: &FrameRow,
    rows: &[Option<&FrameRow>],
    timed: bool,
) -> Vec<String> {
    let when = if timed {
        format!("{:.2} s", row.t)
    } else {
        format!("#{}", row.t as u64)
    };
    if !data.several() {
        return vec![format!("{}  {when}  {}", row.name, values(row))];
    }
    let mut lines = vec![format!("{}  {when}", row.name)];
    for (probe, row) in data.probes.iter().zip(rows) {
        lines.push(format!(
            "{}  {}",
            probe.name,
            row.map_or_else(|| "no row".into(), values)
        ));
    }
    lines
}

/// A row's angle and force, or that it was not detected.
fn values(row: &FrameRow) -> String {
    match (row.detected, row.angle_deg, row.force_nn) {
        (true, Some(a), Some(f)) => {
            let (scale, unit) = force_unit(f.abs());
            format!("{a:+.2}°  {:+.1} {unit}", f * scale)
        }
        _ => "not detected".into(),
    }
}

/// The thumbnails in a grid of `columns`, captions below each, as one picture.
pub fn strip(thumbs: &[Thumbnail], columns: usize) -> Option<RgbImage> {
    let columns = columns.max(1);
    let cell_w = thumbs.iter().map(|t| t.image.width()).max()? + 10;
    let lines = thumbs.iter().map(|t| t.caption.len()).max()?.max(1) as u32;
    let cell_h = thumbs.iter().map(|t| t.image.height()).max()? + 14 + LINE_PX * lines;
    let rows = thumbs.len().div_ceil(columns) as u32;
    let cols = thumbs.len().min(columns) as u32;
    let mut img = RgbImage::from_pixel(cols * cell_w, rows * cell_h, Rgb([255, 255, 255]));
    for (k, t) in thumbs.iter().enumerate() {
        let (x, y) = ((k % columns) as u32 * cell_w, (k / columns) as u32 * cell_h);
        imageops::overlay(&mut img, &t.image, i64::from(x + 5), i64::from(y + 5));
        for (k, line) in t.caption.iter().enumerate() {
            let text_y = (y + 8 + t.image.height() + LINE_PX * k as u32) as i32;
            plot::small_text(&mut img, x as i32 + 5, text_y, line);
        }
    }
    Some(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_takes_first_last_and_even_steps() {
        assert_eq!(spread(10, 4), [0, 3, 6, 9]);
        assert_eq!(spread(3, 8), [0, 1, 2]);
        assert_eq!(spread(5, 1), [0]);
        assert!(spread(0, 4).is_empty());
    }
}
