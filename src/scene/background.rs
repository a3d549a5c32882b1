//! The real-background mode: the probe composited over a crop of a real SEM frame, and
//! the other things a real SEM puts in view (a second, tapered needle).
//!
//! The renderer never reads files: the caller loads the crops (8-bit grey images) and
//! hands them to [`super::Renderer::render_over`]. [`RealLook`] says which crop, and how
//! the frame sees it: a sub-window of it, flipped and magnified as `window_seed` draws
//! them, its grey levels stretched around a chosen mean (so a dark crop can be made into
//! a bright textured background). Everything drawn on top (particles, scratches,
//! substrate, needle, probe) and the SEM effects after it (charging gain, blur, jitter,
//! noise) work as on the synthetic background.

use image::GrayImage;

use super::rng::Rng;

/// How a frame shows a crop of a real SEM frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealLook {
    /// Which of the caller's crops (index modulo their number).
    pub crop: usize,
    /// Seed of the sub-window, flips and zoom: frames of one scene share it.
    pub window_seed: u64,
    /// Smallest magnification of the crop (frame pixels per crop pixel); the window is
    /// drawn at between this and 1.5 times it, never smaller than the frame needs.
    pub zoom: f64,
    /// Mean grey level of the background over the frame.
    pub level: f64,
    /// Standard deviation of the background's grey levels over the frame: the crop's
    /// texture stretched or flattened to it.
    pub texture_sigma: f64,
}

/// A second probe-like object: a straight needle tapering to a point, drawn between the
/// background and the probe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Needle {
    /// Centre of its base (usually beyond the frame's border), pixels.
    pub base: [f64; 2],
    /// Its point, pixels.
    pub tip: [f64; 2],
    /// Width at the base, pixels.
    pub base_width_px: f64,
    /// Grey level.
    pub level: f64,
}

/// Where the window lies in the crop: `crop = origin + frame_px * step` per axis
/// (negative steps flip).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Window {
    origin: [f64; 2],
    step: [f64; 2],
}

impl Window {
    /// The seeded sub-window of a `crop`-sized image seen by a `frame`-sized frame.
    fn draw(real: &RealLook, crop: [u32; 2], frame: [u32; 2]) -> Window {
        let mut rng = Rng::new(real.window_seed);
        let (cw, ch) = (f64::from(crop[0]) - 1.0, f64::from(crop[1]) - 1.0);
        let (fw, fh) = (f64::from(frame[0]), f64::from(frame[1]));
        let fits = (fw / cw).max(fh / ch);
        let zoom = (real.zoom * rng.uniform(1.0, 1.5)).max(fits);
        let span = [fw / zoom, fh / zoom];
        let corner = [
            rng.uniform(0.0, (cw - span[0]).max(0.0)),
            rng.uniform(0.0, (ch - span[1]).max(0.0)),
        ];
        let mut origin = corner;
        let mut step = [1.0 / zoom; 2];
        for (axis, len) in [span[0], span[1]].into_iter().enumerate() {
            if rng.chance(0.5) {
                origin[axis] = corner[axis] + len;
                step[axis] = -step[axis];
            }
        }
        Window { origin, step }
    }
}

/// Fills `canvas` (row-major, `width` wide) with the window of `crop` that `real`
/// draws, bilinearly sampled, its levels stretched to mean `level` and standard
/// deviation `texture_sigma`.
pub fn fill_real(canvas: &mut [f32], width: usize, crop: &GrayImage, real: &RealLook) {
    let height = canvas.len() / width.max(1);
    let win = Window::draw(
        real,
        [crop.width(), crop.height()],
        [width as u32, height as u32],
    );
    let (cw, ch) = (crop.width() as usize, crop.height() as usize);
    let px = crop.as_raw();
    let at = |x: usize, y: usize| f32::from(px[y * cw + x]);
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for (y, row) in canvas.chunks_exact_mut(width).enumerate() {
        let cy = (win.origin[1] + y as f64 * win.step[1]).clamp(0.0, (ch - 1) as f64);
        let (y0, fy) = (cy.floor() as usize, (cy - cy.floor()) as f32);
        let y1 = (y0 + 1).min(ch - 1);
        for (x, v) in row.iter_mut().enumerate() {
            let cx = (win.origin[0] + x as f64 * win.step[0]).clamp(0.0, (cw - 1) as f64);
            let (x0, fx) = (cx.floor() as usize, (cx - cx.floor()) as f32);
            let x1 = (x0 + 1).min(cw - 1);
            let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
            let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
            *v = top + (bottom - top) * fy;
            sum += f64::from(*v);
            sum2 += f64::from(*v) * f64::from(*v);
        }
    }
    let n = canvas.len().max(1) as f64;
    let mean = sum / n;
    let sigma = (sum2 / n - mean * mean).max(0.0).sqrt();
    let gain = if sigma > 1e-3 {
        (real.texture_sigma / sigma) as f32
    } else {
        0.0
    };
    let (level, mean) = (real.level as f32, mean as f32);
    for v in canvas.iter_mut() {
        *v = level + gain * (*v - mean);
    }
}

/// The needle's outline: a quadrilateral from its base (full width) to its point
/// (0.6 px wide, so the point is drawn rather than lost between pixel centres).
pub fn needle_polygon(needle: &Needle, out: &mut Vec<[f64; 2]>) {
    let d = [
        needle.tip[0] - needle.base[0],
        needle.tip[1] - needle.base[1],
    ];
    let len = d[0].hypot(d[1]).max(1e-9);
    let n = [-d[1] / len, d[0] / len];
    let (wb, wt) = (0.5 * needle.base_width_px, 0.3);
    out.clear();
    out.extend([
        [needle.base[0] + wb * n[0], needle.base[1] + wb * n[1]],
        [needle.tip[0] + wt * n[0], needle.tip[1] + wt * n[1]],
        [needle.tip[0] - wt * n[0], needle.tip[1] - wt * n[1]],
        [needle.base[0] - wb * n[0], needle.base[1] - wb * n[1]],
    ]);
}

/// Multiplies the ideal image by the charging gain (brightness drifting over a session).
pub fn charge(canvas: &mut [f32], gain: f64) {
    if gain == 1.0 {
        return;
    }
    let g = gain as f32;
    for v in canvas.iter_mut() {
        *v *= g;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp_crop() -> GrayImage {
        GrayImage::from_fn(64, 48, |x, _| image::Luma([(4 * x) as u8]))
    }

    #[test]
    fn the_window_has_the_chosen_mean_and_texture() {
        let crop = ramp_crop();
        let real = RealLook {
            crop: 0,
            window_seed: 7,
            zoom: 1.0,
            level: 150.0,
            texture_sigma: 12.0,
        };
        let (w, h) = (40, 30);
        let mut canvas = vec![0.0f32; w * h];
        fill_real(&mut canvas, w, &crop, &real);
        let n = (w * h) as f64;
        let mean = canvas.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = canvas
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        assert!((mean - 150.0).abs() < 1e-3, "{mean}");
        assert!((var.sqrt() - 12.0).abs() < 1e-2, "{}", var.sqrt());
        // A horizontal ramp (possibly flipped): every row steps alike.
        let step = (canvas[1] - canvas[0]).abs();
        assert!(step > 0.0);
        assert!(canvas
            .chunks(w)
            .all(|r| ((r[1] - r[0]).abs() - step).abs() < 1e-3));
    }

    #[test]
    fn the_window_is_a_pure_function_of_its_seed() {
        let crop = ramp_crop();
        let real = |seed| RealLook {
            crop: 0,
            window_seed: seed,
            zoom: 1.0,
            level: 100.0,
            texture_sigma: 10.0,
        };
        let fill = |seed| {
            let mut c = vec![0.0f32; 40 * 30];
            fill_real(&mut c, 40, &crop, &real(seed));
            c
        };
        assert_eq!(fill(3), fill(3));
        assert!((0..8).any(|s| fill(s) != fill(3)));
    }

    #[test]
    fn the_needle_tapers_from_its_base_to_its_point() {
        let mut poly = Vec::new();
        let needle = Needle {
            base: [0.0, 10.0],
            tip: [50.0, 10.0],
            base_width_px: 8.0,
            level: 200.0,
        };
        needle_polygon(&needle, &mut poly);
        assert_eq!(
            poly,
            vec![[0.0, 14.0], [50.0, 10.3], [50.0, 9.7], [0.0, 6.0]]
        );
    }
}
