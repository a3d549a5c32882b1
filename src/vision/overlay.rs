//! Pictures for people: the frame with the found edges drawn in red, blue and green and
//! the apex marked (the paper's Figure 8), and the same for a calibration on its
//! reference image, the AFM pyramid's or a rigid probe's named edges. Not used in the
//! hot path.

use image::{GrayImage, Rgb, RgbImage};
use imageproc::drawing::{draw_hollow_circle_mut, draw_line_segment_mut};

use super::rigid::{RigidTemplate, MAX_EDGES};
use super::{Calibration, Edge, Estimate};

const APEX: Rgb<u8> = Rgb([255, 230, 0]);

/// The colours a probe's edges are drawn in, in the calibration's order (the AFM
/// pyramid's red, blue and green first), with the words `nanoforce calibrate` names
/// them by (the apex is marked in yellow).
pub const NAMED_EDGE_COLOURS: [(&str, Rgb<u8>); MAX_EDGES] = [
    ("red", Rgb([255, 40, 40])),
    ("blue", Rgb([60, 110, 255])),
    ("green", Rgb([40, 220, 60])),
    ("magenta", Rgb([230, 60, 230])),
    ("cyan", Rgb([40, 220, 230])),
    ("orange", Rgb([255, 150, 30])),
    ("purple", Rgb([150, 80, 255])),
    ("white", Rgb([255, 255, 255])),
];

/// The frame in colour with the estimate's edges and apex drawn over it.
pub fn draw_overlay(frame: &GrayImage, estimate: &Estimate) -> RgbImage {
    draw_overlays(frame, std::slice::from_ref(estimate))
}

/// The frame in colour with every estimate's edges and apex drawn over it (several
/// probes in one view).
pub fn draw_overlays(frame: &GrayImage, estimates: &[Estimate]) -> RgbImage {
    let mut out = to_rgb(frame);
    for estimate in estimates {
        draw_estimate(&mut out, estimate);
    }
    out
}

/// Each edge in its calibration's colour: the pyramid's red, blue and green, a rigid
/// probe's as [`NAMED_EDGE_COLOURS`] names them.
fn draw_estimate(out: &mut RgbImage, estimate: &Estimate) {
    for (fit, (_, colour)) in estimate.edges.iter().zip(NAMED_EDGE_COLOURS) {
        if let Some(fit) = fit {
            thick_segment(out, fit.start_px, fit.end_px, colour);
        }
    }
    if let Some(apex) = estimate.apex_px {
        mark(out, apex);
    }
}

/// The reference image with the calibrated edge segments and the apex.
pub fn draw_calibration(reference: &GrayImage, calibration: &Calibration) -> RgbImage {
    let mut out = to_rgb(reference);
    for e in Edge::ALL {
        let seg = calibration.edge(e).segment_px;
        thick_segment(&mut out, seg[0], seg[1], NAMED_EDGE_COLOURS[e.index()].1);
    }
    mark(&mut out, calibration.apex_px());
    out
}

/// The reference frame in colour with a rigid probe's calibrated edges drawn over it,
/// each along the stretch the reference shows, bowed as calibrated, in its colour of
/// [`NAMED_EDGE_COLOURS`], and the apex marked.
pub fn draw_rigid_calibration(reference: &GrayImage, template: &RigidTemplate) -> RgbImage {
    const PIECES: usize = 16;
    let mut out = to_rgb(reference);
    for (edge, (_, colour)) in template.edges.iter().zip(NAMED_EDGE_COLOURS) {
        let at = |k: usize| {
            let tau = edge.extent[0] + edge.length() * k as f64 / PIECES as f64;
            let p = edge.point(tau);
            [template.apex[0] + p[0], template.apex[1] + p[1]]
        };
        for k in 0..PIECES {
            thick_segment(&mut out, at(k), at(k + 1), colour);
        }
    }
    mark(&mut out, template.apex);
    out
}

fn to_rgb(frame: &GrayImage) -> RgbImage {
    RgbImage::from_fn(frame.width(), frame.height(), |x, y| {
        let g = frame.get_pixel(x, y)[0];
        Rgb([g, g, g])
    })
}

/// A 2-pixel-wide segment.
fn thick_segment(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], colour: Rgb<u8>) {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy).max(1e-9);
    let (nx, ny) = (-dy / len * 0.5, dx / len * 0.5);
    for k in [-1.0, 1.0] {
        let start = ((a[0] + k * nx) as f32, (a[1] + k * ny) as f32);
        let end = ((b[0] + k * nx) as f32, (b[1] + k * ny) as f32);
        draw_line_segment_mut(img, start, end, colour);
    }
}

fn mark(img: &mut RgbImage, p: [f64; 2]) {
    let c = (p[0].round() as i32, p[1].round() as i32);
    draw_hollow_circle_mut(img, c, 5, APEX);
    draw_hollow_circle_mut(img, c, 6, APEX);
}
