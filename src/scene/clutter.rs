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
        let blobs: Vec<[f64; 4]> = (0..SHADING_BLOBS)
            .map(|_| {
                [
                    rng.uniform(-0.2, 1.2) * w,
                    rng.uniform(-0.2, 1.2) * h,
                    rng.uniform(0.15, 0.4) * w,
                    rng.sign() * rng.uniform(0.5, 1.0),
                ]
            })
            .collect();
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

/// Draws `spec.look.particles` particles into `out`.
pub fn particles(spec: &FrameSpec, rng: &mut Rng, out: &mut Vec<Particle>) {
    let scale = f64::from(spec.width) / 640.0;
    out.clear();
    for _ in 0..spec.look.particles {
        out.push(Particle {
            centre: [
                rng.uniform(0.0, f64::from(spec.width)),
                rng.uniform(0.0, f64::from(spec.height)),
            ],
            radius: 0.5 * rng.uniform(4.0, 30.0) * scale,
            level: (spec.look.background + rng.uniform(50.0, 165.0)).min(250.0),
        });
    }
}

/// Draws `spec.look.scratches` scratches into `out`.
pub fn scratches(spec: &FrameSpec, rng: &mut Rng, out: &mut Vec<Scratch>) {
    let scale = f64::from(spec.width) / 640.0;
    out.clear();
    for _ in 0..spec.look.scratches {
        let centre = [
            rng.uniform(0.0, f64::from(spec.width)),
            rng.uniform(0.0, f64::from(spec.height)),
        ];
        let half = 0.5 * rng.uniform(80.0, 450.0) * scale;
        let (s, c) = rng.uniform(0.0, std::f64::consts::PI).sin_cos();
        out.push(Scratch {
            from: [centre[0] - half * c, centre[1] - half * s],
            to: [centre[0] + half * c, centre[1] + half * s],
            width: rng.uniform(1.5, 4.0) * scale,
            contrast: rng.uniform(20.0, 65.0),
        });
    }
}

/// The substrate as a polygon: everything below a straight edge `gap` below the apex,
/// tilted by `substrate_tilt_deg`, reaching well beyond the frame.
pub fn substrate_polygon(spec: &FrameSpec, out: &mut Vec<[f64; 2]>) {
    let tilt = spec.substrate_tilt_deg.to_radians();
    // Edge direction (screen, CCW tilt) and its downward normal.
    let along = [tilt.cos(), -tilt.sin()];
    let down = [tilt.sin(), tilt.cos()];
    let gap_px = spec.substrate_gap_um * spec.px_per_um();
    let on_edge = [
        spec.apex_px[0] + gap_px * down[0],
        spec.apex_px[1] + gap_px * down[1],
    ];
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
