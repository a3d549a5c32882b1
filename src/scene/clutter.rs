//! Everything in view that is not the probe, drawn from the frame's seed: the slow
//! shading of the background, bright particles of every size, straight scratches at
//! any angle, and the substrate surface just below the apex. Sizes and levels follow
//! the public samples (docs/renderer.md); all lengths scale with the frame's width so
//! a 1280x960 frame looks like a 640x480 one.

use super::rng::Rng;
use super::spec::FrameSpec;

/// A bright disc, pixels and grey levels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Particle {
    pub centre: [f64; 2],
    pub radius: f64,
    pub level: f64,
}

/// A thin straight bright line segment, added to what is behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scratch {
    pub from: [f64; 2],
    pub to: [f64; 2],
    pub width: f64,
    pub contrast: f64,
}

/// The shading grid's cell size, pixels (at 640 px width).
const SHADING_CELL_PX: f64 = 16.0;
const SHADING_BLOBS: usize = 5;

/// The background's slow shading on a coarse grid: `values[j * cols + i]` is the level
/// at pixel (i * cell, j * cell).
#[derive(Debug, Default)]
pub struct Shading {
    pub cell: f64,
    pub cols: usize,
    pub rows: usize,
    pub values: Vec<f32>,
}

impl Shading {
    /// Fills the grid: a sum of a few broad Gaussian blobs, stretched to
    /// `background +- shading`.
    pub fn generate(&mut self, spec: &FrameSpec, rng: &mut Rng) {
        let w = f64::from(spec.width);
        let h = f64::from(spec.height);
        self.cell = SHADING_CELL_PX * w / 640.0;
        self.cols = (w / self.cell).ceil() as usize + 2;
        self.rows = (h / self.cell).ceil() as usize + 2;
        let blobs: [[f64; 4]; SHADING_BLOBS] = std::array::from_fn(|_| {
            [
                rng.uniform(-0.2, 1.2) * w,
                rng.uniform(-0.2, 1.2) * h,
                rng.uniform(0.15, 0.4) * w,
                rng.sign() * rng.uniform(0.5, 1.0),
            ]
        });
        self.values.clear();
        for j in 0..self.rows {
            for i in 0..self.cols {
                let (x, y) = (i as f64 * self.cell, j as f64 * self.cell);
                let v: f64 = blobs
                    .iter()
                    .map(|b| {
                        b[3] * (-((x - b[0]).powi(2) + (y - b[1]).powi(2)) / (2.0 * b[2] * b[2]))
                            .exp()
                    })
                    .sum();
                self.values.push(v as f32);
            }
        }
        let lo = self.values.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = self
            .values
            .iter()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        let span = (hi - lo).max(1e-6);
        let (base, amp) = (spec.look.background as f32, spec.look.shading as f32);
        for v in &mut self.values {
            *v = base + amp * (2.0 * (*v - lo) / span - 1.0);
        }
    }

    /// Writes the bilinearly interpolated shading into a row-major frame; `line` is
    /// scratch space for one interpolated grid row.
    pub fn fill(&self, canvas: &mut [f32], width: usize, line: &mut Vec<f32>) {
        let inv = 1.0 / self.cell;
        line.resize(self.cols, 0.0);
        for (y, row) in canvas.chunks_exact_mut(width).enumerate() {
            let fy = y as f64 * inv;
            let j = (fy as usize).min(self.rows - 2);
            let ty = (fy - j as f64) as f32;
            let top = &self.values[j * self.cols..(j + 1) * self.cols];
            let bottom = &self.values[(j + 1) * self.cols..(j + 2) * self.cols];
            for ((l, &t), &b) in line.iter_mut().zip(top).zip(bottom) {
                *l = t + (b - t) * ty;
            }
            // Linear ramps between grid columns.
            let mut x = 0usize;
            for i in 0..self.cols - 1 {
                let end = (((i + 1) as f64 * self.cell).ceil() as usize).min(width);
                let slope = (line[i + 1] - line[i]) * inv as f32;
                let origin = i as f64 * self.cell;
                for (k, out) in row[x..end].iter_mut().enumerate() {
                    *out = line[i] + slope * ((x + k) as f64 - origin) as f32;
                }
                x = end;
                if x >= width {
                    break;
                }
            }
        }
    }
}

/// Draws `spec.look.particles` particles into `out`, on the background (as in the
/// public samples, the substrate hides what lies behind it).
pub fn particles(spec: &FrameSpec, rng: &mut Rng, out: &mut Vec<Particle>) {
    let scale = f64::from(spec.width) / 640.0;
    out.clear();
    for _ in 0..spec.look.particles {
        out.push(Particle {
            centre: background_point(spec, rng),
            radius: 0.5 * rng.uniform(4.0, 30.0) * scale,
            level: (spec.look.background + rng.uniform(50.0, 165.0)).min(250.0),
        });
    }
}

/// Draws `spec.look.scratches` scratches into `out`, centred on the background.
pub fn scratches(spec: &FrameSpec, rng: &mut Rng, out: &mut Vec<Scratch>) {
    let scale = f64::from(spec.width) / 640.0;
    out.clear();
    for _ in 0..spec.look.scratches {
        let centre = background_point(spec, rng);
        let half = 0.5 * rng.uniform(80.0, 450.0) * scale;
        let (s, c) = rng.uniform(0.0, std::f64::consts::PI).sin_cos();
        out.push(Scratch {
            from: [centre[0] - half * c, centre[1] - half * s],
            to: [centre[0] + half * c, centre[1] + half * s],
            width: rng.uniform(1.5, 4.0) * scale,
            contrast: rng.uniform(25.0, 75.0),
        });
    }
}

/// A uniformly random pixel position not on the substrate (a few tries, then anywhere).
fn background_point(spec: &FrameSpec, rng: &mut Rng) -> [f64; 2] {
    let mut p = [0.0; 2];
    for _ in 0..8 {
        p = [
            rng.uniform(0.0, f64::from(spec.width)),
            rng.uniform(0.0, f64::from(spec.height)),
        ];
        if spec.look.substrate.is_none() || substrate_depth(spec, p) < 0.0 {
            break;
        }
    }
    p
}

/// The substrate's edge: a point on it and its downward normal.
fn substrate_edge(spec: &FrameSpec) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let tilt = spec.substrate_tilt_deg.to_radians();
    let along = [tilt.cos(), -tilt.sin()];
    let down = [tilt.sin(), tilt.cos()];
    let gap_px = spec.substrate_gap_um * spec.px_per_um();
    let on_edge = [
        spec.apex_px[0] + gap_px * down[0],
        spec.apex_px[1] + gap_px * down[1],
    ];
    (on_edge, along, down)
}

/// How far below the substrate's edge `p` lies, pixels (negative above it).
fn substrate_depth(spec: &FrameSpec, p: [f64; 2]) -> f64 {
    let (on_edge, _, down) = substrate_edge(spec);
    (p[0] - on_edge[0]) * down[0] + (p[1] - on_edge[1]) * down[1]
}

/// The substrate as a polygon: everything below a straight edge `gap` below the apex,
/// tilted by `substrate_tilt_deg`, reaching well beyond the frame.
pub fn substrate_polygon(spec: &FrameSpec, out: &mut Vec<[f64; 2]>) {
    let (on_edge, along, down) = substrate_edge(spec);
    let reach = 4.0 * f64::from(spec.width.max(spec.height));
    out.clear();
    for (a, d) in [(-reach, 0.0), (reach, 0.0), (reach, reach), (-reach, reach)] {
        out.push([
            on_edge[0] + a * along[0] + d * down[0],
            on_edge[1] + a * along[1] + d * down[1],
        ]);
    }
}

/// A thin rectangle around a scratch's centre line.
pub fn scratch_polygon(s: &Scratch, out: &mut Vec<[f64; 2]>) {
    let d = [s.to[0] - s.from[0], s.to[1] - s.from[1]];
    let len = d[0].hypot(d[1]).max(1e-9);
    let n = [-d[1] / len * 0.5 * s.width, d[0] / len * 0.5 * s.width];
    out.clear();
    out.extend([
        [s.from[0] + n[0], s.from[1] + n[1]],
        [s.to[0] + n[0], s.to[1] + n[1]],
        [s.to[0] - n[0], s.to[1] - n[1]],
        [s.from[0] - n[0], s.from[1] - n[1]],
    ]);
}

/// A disc as a polygon with edges of about one pixel (area error < 1/(8 r) px).
pub fn disc_polygon(p: &Particle, out: &mut Vec<[f64; 2]>) {
    let n = ((std::f64::consts::TAU * p.radius).ceil() as usize).clamp(12, 512);
    out.clear();
    for k in 0..n {
        let (s, c) = (std::f64::consts::TAU * k as f64 / n as f64).sin_cos();
        out.push([p.centre[0] + p.radius * c, p.centre[1] + p.radius * s]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::spec::Style;

    #[test]
    fn clutter_lies_on_the_background_not_the_substrate() {
        let mut spec = FrameSpec::new(Style::Harsh, 0.0, 1);
        spec.look.particles = 400;
        spec.substrate_tilt_deg = 4.0;
        let mut out = Vec::new();
        particles(&spec, &mut Rng::new(5), &mut out);
        let on_substrate = out
            .iter()
            .filter(|p| substrate_depth(&spec, p.centre) > 0.0)
            .count();
        // Eight tries each: only a tiny share may land on the substrate.
        assert!(on_substrate <= 4, "{on_substrate} of 400");
        assert!(out.iter().all(|p| (2.0..=15.0).contains(&p.radius)));
    }

    #[test]
    fn shading_spans_background_plus_minus_amplitude() {
        let spec = FrameSpec::new(Style::Clean, 0.0, 9);
        let mut shading = Shading::default();
        shading.generate(&spec, &mut Rng::new(3));
        let (w, h) = (spec.width as usize, spec.height as usize);
        let mut canvas = vec![0.0f32; w * h];
        shading.fill(&mut canvas, w, &mut Vec::new());
        let lo = canvas.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = canvas.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let (b, a) = (spec.look.background as f32, spec.look.shading as f32);
        assert!(lo >= b - a - 1e-3 && hi <= b + a + 1e-3, "{lo}..{hi}");
        assert!(hi - lo > a, "visible shading: {lo}..{hi}");
        // Smooth: neighbouring pixels differ by a small fraction of a grey level.
        let step = canvas.windows(2).map(|p| (p[1] - p[0]).abs()).take(w - 1);
        assert!(step.fold(0.0f32, f32::max) < 0.5);
    }
}
