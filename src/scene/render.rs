//! The rendering pipeline: an ideal image with exact area coverage of every shape
//! (shading, scratches, particles, substrate, probe with its brighter outline), then the
//! SEM: Gaussian beam blur, scan-line jitter, white Gaussian noise, 8-bit quantisation.
//! [`Renderer`] owns every buffer, so rendering into a reused frame allocates nothing
//! once the first frame of a size has been drawn.

use image::GrayImage;

use super::background::{charge, fill_real, needle_polygon};
use super::blur::Blur;
use super::clutter::{self, Particle, Scratch, Shading};
use super::geometry::{probe_outline, Edges};
use super::raster::Rasterizer;
use super::rng::{add_gaussian_noise, sub_seed, Rng};
use super::spec::FrameSpec;
use super::tool::tool_outline;

/// The true values of everything the tracker reports for one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// The probe is in view (truth.csv `detected`); false for blank frames.
    pub probe_in_view: bool,
    /// Tip angle, degrees CCW on screen (NaN when not in view).
    pub angle_deg: f64,
    /// sign(angle) alpha(|angle|) EI / L^2, nanonewtons (NaN when not in view).
    pub force_nn: f64,
    /// The apex, pixels (NaN when not in view).
    pub tip_x: f64,
    pub tip_y: f64,
    pub magnification: f64,
    pub px_per_um: f64,
    /// The three tracked edges (None when not in view, and for a tool: see
    /// [`super::tool_truth`]).
    pub edges: Option<Edges>,
}

/// Independent random streams of a frame.
const STREAM_SHADING: u64 = 1;
const STREAM_PARTICLES: u64 = 2;
const STREAM_SCRATCHES: u64 = 3;
const STREAM_JITTER: u64 = 4;
const STREAM_NOISE: u64 = 5;

/// Blur sigma the buffers are prepared for when a frame size is first seen (a larger
/// sigma still works; its first frame grows the buffers).
const MAX_PREPARED_BLUR_PX: f64 = 3.0;

/// Renders frames; keeps its buffers between calls.
#[derive(Debug, Default)]
pub struct Renderer {
    canvas: Vec<f32>,
    raster: Rasterizer,
    blur: Blur,
    shading: Shading,
    particles: Vec<Particle>,
    scratches: Vec<Scratch>,
    polygon: Vec<[f64; 2]>,
    inset: Vec<[f64; 2]>,
    row: Vec<f32>,
    line: Vec<f32>,
}

impl Renderer {
    pub fn new() -> Self {
        Renderer::default()
    }

    /// Renders `spec` into `frame` (reallocated only if its size differs) and returns
    /// the truth.
    pub fn render_into(&mut self, spec: &FrameSpec, frame: &mut GrayImage) -> Truth {
        self.render_over(spec, &[], frame)
    }

    /// As [`Renderer::render_into`], with the caller's crops of real SEM frames: when
    /// `spec.look.real` names one (index modulo `crops.len()`), the frame shows its
    /// seeded window instead of the synthetic shading. Without crops the synthetic
    /// background is drawn.
    pub fn render_over(
        &mut self,
        spec: &FrameSpec,
        crops: &[GrayImage],
        frame: &mut GrayImage,
    ) -> Truth {
        let truth = self.render_canvas_over(spec, crops);
        if frame.dimensions() != (spec.width, spec.height) {
            *frame = GrayImage::new(spec.width, spec.height);
        }
        for (out, &v) in frame.iter_mut().zip(&self.canvas) {
            // `as` saturates: negatives (and NaN) give 0, above 255 gives 255.
            *out = (v + 0.5) as u8;
        }
        truth
    }

    /// Renders the noisy frame into the internal f32 canvas (grey levels, unclamped).
    pub fn render_canvas(&mut self, spec: &FrameSpec) -> Truth {
        self.render_canvas_over(spec, &[])
    }

    /// As [`Renderer::render_canvas`], over the caller's crops (see
    /// [`Renderer::render_over`]).
    pub fn render_canvas_over(&mut self, spec: &FrameSpec, crops: &[GrayImage]) -> Truth {
        let (w, h) = (spec.width as usize, spec.height as usize);
        if self.canvas.len() != w * h {
            // Room for the longest outlines a frame of this size can need (the beam is
            // sampled every 6 px across up to about twice the frame), so later frames
            // of any pose do not grow these buffers.
            let vertices = 8 * (w + h);
            for v in [&mut self.polygon, &mut self.inset] {
                v.reserve(vertices.saturating_sub(v.len()));
            }
            self.particles.reserve(64);
            self.scratches.reserve(16);
            self.row.reserve(w);
            self.blur.reserve(w, MAX_PREPARED_BLUR_PX);
        }
        self.canvas.resize(w * h, 0.0);
        self.raster.resize(spec.width, spec.height);
        self.draw_background(spec, crops);
        if let Some(needle) = spec.look.needle {
            needle_polygon(&needle, &mut self.polygon);
            let level = needle.level as f32;
            paint_over(&mut self.raster, &self.polygon, &mut self.canvas, w, |_| {
                level
            });
        }
        let truth = self.draw_probe(spec);
        for k in 1..spec.probe_count() {
            if let Some(other) = spec.nth_probe(k) {
                self.draw_probe(&other);
            }
        }
        charge(&mut self.canvas, spec.look.charging_gain);
        self.blur
            .apply(&mut self.canvas, w, h, spec.look.blur_sigma_px);
        self.jitter(spec);
        let mut rng = Rng::new(sub_seed(spec.seed, STREAM_NOISE));
        add_gaussian_noise(&mut self.canvas, spec.look.noise_sigma as f32, &mut rng);
        truth
    }

    /// The rendered canvas of the last call (row-major, grey levels before quantising).
    pub fn canvas(&self) -> &[f32] {
        &self.canvas
    }

    fn draw_background(&mut self, spec: &FrameSpec, crops: &[GrayImage]) {
        let w = spec.width as usize;
        match spec.look.real.filter(|_| !crops.is_empty()) {
            Some(real) => fill_real(&mut self.canvas, w, &crops[real.crop % crops.len()], &real),
            None => {
                let mut rng = Rng::new(sub_seed(spec.seed, STREAM_SHADING));
                self.shading.generate(spec, &mut rng);
                self.shading.fill(&mut self.canvas, w, &mut self.line);
            }
        }
        let mut rng = Rng::new(sub_seed(spec.seed, STREAM_SCRATCHES));
        clutter::scratches(spec, &mut rng, &mut self.scratches);
        for s in &self.scratches {
            clutter::scratch_polygon(s, &mut self.polygon);
            let canvas = &mut self.canvas;
            let contrast = s.contrast as f32;
            self.raster
                .fill(&self.polygon, |x, y, c| canvas[y * w + x] += contrast * c);
        }
        let mut rng = Rng::new(sub_seed(spec.seed, STREAM_PARTICLES));
        clutter::particles(spec, &mut rng, &mut self.particles);
        for p in &self.particles {
            clutter::disc_polygon(p, &mut self.polygon);
            paint_over(&mut self.raster, &self.polygon, &mut self.canvas, w, |_| {
                p.level as f32
            });
        }
        if let Some(level) = spec.look.substrate {
            clutter::substrate_polygon(spec, &mut self.polygon);
            paint_over(&mut self.raster, &self.polygon, &mut self.canvas, w, |_| {
                level as f32
            });
        }
    }

    fn draw_probe(&mut self, spec: &FrameSpec) -> Truth {
        if spec.blank {
            return truth_from(spec, None);
        }
        let w = spec.width as usize;
        let edges = match &spec.tool {
            Some(tool) => {
                tool_outline(
                    tool,
                    &spec.pose(),
                    spec.width,
                    spec.height,
                    &mut self.polygon,
                );
                None
            }
            None => Some(probe_outline(
                &spec.probe,
                &spec.pose(),
                spec.width,
                spec.height,
                &mut self.polygon,
            )),
        };
        let look = spec.look;
        if look.edge_bias_px != 0.0 {
            // The imaged outline: every side moved out by the bias (mitred corners, so
            // the apex moves bias / sin(half its angle) along its bisector).
            inset_polygon(&self.polygon, -look.edge_bias_px, &mut self.inset);
            std::mem::swap(&mut self.polygon, &mut self.inset);
        }
        let ramp = (look.probe_ramp / f64::from(spec.width)) as f32;
        let level0 = (look.probe - 0.5 * look.probe_ramp) as f32;
        let level = |x: usize| level0 + ramp * x as f32;
        let rim = look.outline as f32;
        if rim != 0.0 && look.outline_width_px > 0.0 {
            paint_over(&mut self.raster, &self.polygon, &mut self.canvas, w, |x| {
                level(x) + rim
            });
            inset_polygon(&self.polygon, look.outline_width_px, &mut self.inset);
            paint_over(&mut self.raster, &self.inset, &mut self.canvas, w, level);
        } else {
            paint_over(&mut self.raster, &self.polygon, &mut self.canvas, w, level);
        }
        truth_from(spec, edges)
    }

    /// Shifts a random `jitter_fraction` of the rows one pixel left or right.
    fn jitter(&mut self, spec: &FrameSpec) {
        if spec.look.jitter_fraction <= 0.0 {
            return;
        }
        let w = spec.width as usize;
        let mut rng = Rng::new(sub_seed(spec.seed, STREAM_JITTER));
        self.row.resize(w, 0.0);
        for row in self.canvas.chunks_exact_mut(w) {
            if !rng.chance(spec.look.jitter_fraction) {
                continue;
            }
            self.row.copy_from_slice(row);
            if rng.sign() > 0.0 {
                row[1..].copy_from_slice(&self.row[..w - 1]);
            } else {
                row[..w - 1].copy_from_slice(&self.row[1..]);
            }
        }
    }
}

/// The truth of `spec`'s own probe, without drawing it: what rendering `spec` returns
/// (for another probe of a frame, [`FrameSpec::nth_probe`]).
pub fn truth_of(spec: &FrameSpec) -> Truth {
    if spec.blank {
        return truth_from(spec, None);
    }
    let mut outline = Vec::new();
    let edges = spec.tool.is_none().then(|| {
        probe_outline(
            &spec.probe,
            &spec.pose(),
            spec.width,
            spec.height,
            &mut outline,
        )
    });
    truth_from(spec, edges)
}

/// The truth of `spec`'s probe with its true `edges` (none for a tool, whose edges
/// [`super::tool_truth`] gives; its force is NaN).
fn truth_from(spec: &FrameSpec, edges: Option<Edges>) -> Truth {
    let ppu = spec.px_per_um();
    if spec.blank {
        return Truth {
            probe_in_view: false,
            angle_deg: f64::NAN,
            force_nn: f64::NAN,
            tip_x: f64::NAN,
            tip_y: f64::NAN,
            magnification: spec.magnification,
            px_per_um: ppu,
            edges: None,
        };
    }
    Truth {
        probe_in_view: true,
        angle_deg: spec.angle_deg,
        force_nn: if spec.tool.is_some() {
            f64::NAN
        } else {
            force_nn(spec)
        },
        tip_x: spec.apex_px[0],
        tip_y: spec.apex_px[1],
        magnification: spec.magnification,
        px_per_um: ppu,
        edges,
    }
}

/// The true tip force: sign(angle) alpha(|angle|) EI / L^2 from the exact elastica.
pub fn force_nn(spec: &FrameSpec) -> f64 {
    let scale_nn = spec.probe.cantilever().force_scale_nn();
    match crate::model::exact(spec.angle_deg.to_radians()) {
        Ok(e) => e.alpha * scale_nn,
        Err(_) => f64::NAN,
    }
}

/// Composites a polygon over the canvas with area coverage: v += (level(x) - v) * c.
fn paint_over(
    raster: &mut Rasterizer,
    polygon: &[[f64; 2]],
    canvas: &mut [f32],
    width: usize,
    level: impl Fn(usize) -> f32,
) {
    raster.fill(polygon, |x, y, c| {
        let v = &mut canvas[y * width + x];
        *v += (level(x) - *v) * c;
    });
}

/// Offsets a simple closed polygon inward by `d` pixels (outward for a negative `d`;
/// mitred corners); the band between the two is the probe's bright outline.
fn inset_polygon(polygon: &[[f64; 2]], d: f64, out: &mut Vec<[f64; 2]>) {
    let n = polygon.len();
    let area2: f64 = (0..n)
        .map(|i| {
            let (p, q) = (polygon[i], polygon[(i + 1) % n]);
            p[0] * q[1] - q[0] * p[1]
        })
        .sum();
    // Inward normal of edge p->q: left normal for a counter-clockwise (in y-down
    // coordinates: negative area) polygon, right normal otherwise.
    let sign = if area2 > 0.0 { 1.0 } else { -1.0 };
    let normal = |p: [f64; 2], q: [f64; 2]| {
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        let len = dx.hypot(dy).max(1e-12);
        [-dy / len * sign, dx / len * sign]
    };
    out.clear();
    for i in 0..n {
        let prev = polygon[(i + n - 1) % n];
        let cur = polygon[i];
        let next = polygon[(i + 1) % n];
        let (n1, n2) = (normal(prev, cur), normal(cur, next));
        let k = d / (1.0 + n1[0] * n2[0] + n1[1] * n2[1]).max(0.05);
        out.push([cur[0] + k * (n1[0] + n2[0]), cur[1] + k * (n1[1] + n2[1])]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inset_square_shrinks_by_d_on_every_side() {
        let sq = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]];
        let mut out = Vec::new();
        inset_polygon(&sq, 1.0, &mut out);
        assert_eq!(out, vec![[1.0, 1.0], [9.0, 1.0], [9.0, 9.0], [1.0, 9.0]]);
        let rev: Vec<_> = sq.iter().rev().copied().collect();
        inset_polygon(&rev, 1.0, &mut out);
        assert_eq!(out, vec![[1.0, 9.0], [9.0, 9.0], [9.0, 1.0], [1.0, 1.0]]);
    }
}
