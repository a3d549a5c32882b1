//! Frames that do not show a session's probe, made to fool a tracker calibrated on it:
//! the tracker's adversarial suite (docs/tracker.md, "What the tracker refuses, and
//! why"). Each [`Decoy`] is one way a frame can look probe-like without being this
//! probe; [`Adversary::render_into`] draws one, deterministic from a seed, in the
//! session's frame size, looks and magnifications.
//!
//! Shapes and occluders are painted on the renderer's ideal (noise- and blur-free)
//! canvas and then blurred and noised like everything else, so their edges look like
//! the probe's.

use image::GrayImage;

use super::blur::Blur;
use super::generate::random_frame;
use super::geometry::{probe_outline, ProbeGeometry};
use super::raster::Rasterizer;
use super::render::Renderer;
use super::rng::{add_gaussian_noise, sub_seed, Rng};
use super::session::{Session, Setup};
use super::spec::{FrameSpec, Style};

/// What an adversarial frame shows instead of the session's probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Decoy {
    /// Many scratches and particles, no probe.
    Clutter,
    /// Random bright and dark polygons, triangles and beam-like strips.
    Shapes,
    /// The session's own probe mirrored left-right.
    Mirrored,
    /// A probe of another geometry: another beam thickness or other pyramid angles.
    OtherProbe,
    /// The session's probe with its tip hidden under an occluding patch.
    Occluded,
}

impl Decoy {
    pub const ALL: [Decoy; 5] = [
        Decoy::Clutter,
        Decoy::Shapes,
        Decoy::Mirrored,
        Decoy::OtherProbe,
        Decoy::Occluded,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Decoy::Clutter => "clutter",
            Decoy::Shapes => "shapes",
            Decoy::Mirrored => "mirrored",
            Decoy::OtherProbe => "other-probe",
            Decoy::Occluded => "occluded",
        }
    }
}

/// Most placements drawn for a mirrored or other probe before the last is kept.
const MAX_REDRAWS: usize = 64;
/// How far inside the frame the tip's corners must lie, pixels.
const WHOLE_TIP_MARGIN_PX: f64 = 8.0;

/// Whether the frame of `spec` shows the probe's whole tip: the apex, the pyramid's
/// base on both faces and the beam's free end, each `WHOLE_TIP_MARGIN_PX` inside.
/// `outline` is scratch space.
pub fn shows_whole_tip(spec: &FrameSpec, outline: &mut Vec<[f64; 2]>) -> bool {
    let e = probe_outline(&spec.probe, &spec.pose(), spec.width, spec.height, outline);
    let (w, h) = (f64::from(spec.width), f64::from(spec.height));
    let m = WHOLE_TIP_MARGIN_PX;
    [e.red.to, e.blue.from, e.blue.to, e.green.to]
        .iter()
        .all(|p| p[0] >= m && p[1] >= m && p[0] <= w - 1.0 - m && p[1] <= h - 1.0 - m)
}

/// Random streams of an adversarial frame.
const STREAM_FRAME: u64 = 1;
const STREAM_SHAPES: u64 = 2;
const STREAM_NOISE: u64 = 3;

/// Draws adversarial frames; keeps its buffers between calls.
#[derive(Debug, Default)]
pub struct Adversary {
    renderer: Renderer,
    canvas: Vec<f32>,
    raster: Rasterizer,
    blur: Blur,
    polygon: Vec<[f64; 2]>,
    /// Width of the canvas, pixels.
    width: usize,
}

/// The fixed part of `session` (probe, frame size, entry side, base orientation).
pub fn setup_of(session: &Session) -> Setup {
    let r = &session.reference;
    Setup {
        probe: r.probe,
        width: r.width,
        height: r.height,
        entry: r.entry,
        base_deg: r.base_deg,
    }
}

impl Adversary {
    pub fn new() -> Self {
        Adversary::default()
    }

    /// Draws a frame of kind `decoy` for `session` into `frame`; returns the spec the
    /// frame started from (its look, magnification, and for the probe-based kinds the
    /// probe's pose before it was mirrored, changed or hidden).
    pub fn render_into(
        &mut self,
        session: &Session,
        decoy: Decoy,
        seed: u64,
        frame: &mut GrayImage,
    ) -> FrameSpec {
        let setup = setup_of(session);
        let mut rng = Rng::new(sub_seed(seed, STREAM_FRAME));
        let style = Style::ALL[rng.int(0, 3) as usize];
        let mag = rng.log_uniform(1000.0, 8000.0).round();
        let angle = rng.uniform(-20.0, 20.0);
        let mut spec = random_frame(&setup, style, mag, angle, &mut rng);
        spec.blank = false;
        let mut shapes = Rng::new(sub_seed(seed, STREAM_SHAPES));
        // The probe this frame draws: the session's, or for another probe, its
        // geometry changed.
        let drawn = match decoy {
            Decoy::OtherProbe => other_geometry(&spec.probe, &mut shapes),
            _ => spec.probe,
        };
        if matches!(decoy, Decoy::Mirrored | Decoy::OtherProbe) {
            // Only the whole tip tells these from the probe: the wedge alone, mirrored, is
            // the probe's wedge turned, and another beam is out of view. The magnification
            // and placement are drawn again until the drawn probe's beam free end (both
            // faces of the beam) and its pyramid's base are in the frame.
            for _ in 0..MAX_REDRAWS {
                let mut shown = spec;
                shown.probe = drawn;
                if shows_whole_tip(&shown, &mut self.polygon) {
                    break;
                }
                let mag = rng.log_uniform(1000.0, 8000.0).round();
                spec = random_frame(&setup, style, mag, angle, &mut rng);
                spec.blank = false;
            }
        }
        match decoy {
            Decoy::Clutter => {
                spec.blank = true;
                spec.look.particles = shapes.int(10, 40);
                spec.look.scratches = shapes.int(4, 14);
                self.renderer.render_into(&spec, frame);
            }
            Decoy::Mirrored => {
                self.renderer.render_into(&spec, frame);
                image::imageops::flip_horizontal_in_place(frame);
            }
            Decoy::OtherProbe => {
                let mut other = spec;
                other.probe = drawn;
                self.renderer.render_into(&other, frame);
            }
            Decoy::Shapes => {
                spec.blank = true;
                self.ideal(&spec);
                let n = shapes.int(1, 4);
                for _ in 0..n {
                    self.shape(&spec, &mut shapes);
                }
                self.finish(&spec, seed, frame);
            }
            Decoy::Occluded => {
                self.ideal(&spec);
                self.occluder(&spec, &mut shapes);
                self.finish(&spec, seed, frame);
            }
        }
        spec
    }

    /// Renders `spec` without blur, jitter or noise into `self.canvas`.
    fn ideal(&mut self, spec: &FrameSpec) {
        let mut plain = *spec;
        plain.look.noise_sigma = 0.0;
        plain.look.blur_sigma_px = 0.0;
        plain.look.jitter_fraction = 0.0;
        self.renderer.render_canvas(&plain);
        self.canvas.clear();
        self.canvas.extend_from_slice(self.renderer.canvas());
        self.raster.resize(spec.width, spec.height);
        self.width = spec.width as usize;
    }

    /// Blurs and noises the canvas as the renderer would, and quantises it.
    fn finish(&mut self, spec: &FrameSpec, seed: u64, frame: &mut GrayImage) {
        let (w, h) = (spec.width as usize, spec.height as usize);
        self.blur
            .apply(&mut self.canvas, w, h, spec.look.blur_sigma_px);
        let mut rng = Rng::new(sub_seed(seed, STREAM_NOISE));
        add_gaussian_noise(&mut self.canvas, spec.look.noise_sigma as f32, &mut rng);
        if frame.dimensions() != (spec.width, spec.height) {
            *frame = GrayImage::new(spec.width, spec.height);
        }
        for (out, &v) in frame.iter_mut().zip(&self.canvas) {
            *out = (v + 0.5) as u8;
        }
    }

    /// Paints `self.polygon` at `level` over the canvas (area coverage).
    fn paint(&mut self, level: f64) {
        let w = self.width;
        let canvas = &mut self.canvas;
        let level = level as f32;
        self.raster.fill(&self.polygon, |x, y, c| {
            let v = &mut canvas[y * w + x];
            *v += (level - *v) * c;
        });
    }

    /// One random bright or dark shape: a polygon, a triangle or a beam-like strip, at
    /// the size of a probe at this magnification.
    fn shape(&mut self, spec: &FrameSpec, rng: &mut Rng) {
        let ppu = spec.px_per_um();
        let size = rng.uniform(8.0, 30.0) * ppu;
        let (w, h) = (f64::from(spec.width), f64::from(spec.height));
        let c = [rng.uniform(0.1, 0.9) * w, rng.uniform(0.1, 0.9) * h];
        let turn = rng.uniform(0.0, std::f64::consts::TAU);
        self.polygon.clear();
        match rng.int(0, 2) {
            0 => {
                // A star-shaped polygon of 4-8 vertices.
                let n = rng.int(4, 8);
                for k in 0..n {
                    let a = turn
                        + std::f64::consts::TAU * (k as f64 + rng.uniform(-0.3, 0.3)) / n as f64;
                    let r = size * rng.uniform(0.3, 1.0);
                    self.polygon.push([c[0] + r * a.cos(), c[1] + r * a.sin()]);
                }
            }
            1 => {
                // A triangle with a corner of 30-80 deg at c.
                let opening = rng.uniform(30.0, 80.0).to_radians();
                for (a, r) in [
                    (0.0, 0.0),
                    (turn, size * rng.uniform(0.5, 1.5)),
                    (turn + opening, size * rng.uniform(0.5, 1.5)),
                ] {
                    self.polygon.push([c[0] + r * a.cos(), c[1] + r * a.sin()]);
                }
            }
            _ => {
                // A strip running off the frame, 1.5-6 um thick, sometimes with a tooth
                // hanging from its end.
                let thick = rng.uniform(1.5, 6.0) * ppu;
                let d = [turn.cos(), turn.sin()];
                let n = [-d[1], d[0]];
                let far = 2.0 * (w + h);
                let at = |s: f64, t: f64| [c[0] + s * d[0] + t * n[0], c[1] + s * d[1] + t * n[1]];
                self.polygon
                    .extend([at(0.0, 0.0), at(-far, 0.0), at(-far, thick)]);
                if rng.chance(0.5) {
                    let tooth = rng.uniform(5.0, 16.0) * ppu;
                    let back = rng.uniform(0.5, 1.5) * tooth;
                    let front = rng.uniform(0.0, 0.5) * tooth;
                    self.polygon.extend([
                        at(-back - front, thick),
                        at(-front, thick + tooth),
                        at(0.0, thick),
                    ]);
                } else {
                    self.polygon.push(at(0.0, thick));
                }
            }
        }
        let bg = spec.look.background;
        let level = if rng.chance(0.6) {
            (bg + rng.uniform(60.0, 160.0)).min(250.0)
        } else {
            (bg - rng.uniform(30.0, 70.0)).max(5.0)
        };
        self.paint(level);
    }

    /// A patch over the probe's apex, of a random level, hiding the tip.
    fn occluder(&mut self, spec: &FrameSpec, rng: &mut Rng) {
        let pyramid_px = spec.probe.pyramid_height_um * spec.px_per_um();
        let r = rng.uniform(0.3, 0.7) * pyramid_px;
        let c = [
            spec.apex_px[0] + rng.uniform(-0.3, 0.3) * r,
            spec.apex_px[1] + rng.uniform(-0.3, 0.3) * r,
        ];
        self.polygon.clear();
        if rng.chance(0.5) {
            // A rectangle: straight borders a face may lock onto.
            let turn = rng.uniform(0.0, std::f64::consts::PI);
            let (d, n) = ([turn.cos(), turn.sin()], [-turn.sin(), turn.cos()]);
            let (a, b) = (r * rng.uniform(0.8, 1.6), r * rng.uniform(0.8, 1.6));
            for (s, t) in [(-a, -b), (a, -b), (a, b), (-a, b)] {
                self.polygon
                    .push([c[0] + s * d[0] + t * n[0], c[1] + s * d[1] + t * n[1]]);
            }
        } else {
            let n = 48;
            for k in 0..n {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                self.polygon.push([c[0] + r * a.cos(), c[1] + r * a.sin()]);
            }
        }
        let level = match rng.int(0, 2) {
            0 => spec.look.background + rng.uniform(-10.0, 10.0),
            1 => (spec.look.background + rng.uniform(40.0, 150.0)).min(250.0),
            _ => (spec.look.background - rng.uniform(20.0, 60.0)).max(5.0),
        };
        self.paint(level);
    }
}

/// A probe clearly unlike `p`: the beam 2-3 times thicker or thinner, or a pyramid face
/// turned by 10-20 deg.
fn other_geometry(p: &ProbeGeometry, rng: &mut Rng) -> ProbeGeometry {
    let mut q = *p;
    match rng.int(0, 2) {
        0 => {
            let factor = rng.uniform(2.0, 3.0);
            q.thickness_um = if rng.chance(0.5) {
                p.thickness_um * factor
            } else {
                p.thickness_um / factor
            };
        }
        1 => {
            let turn = rng.uniform(10.0, 20.0) * rng.sign();
            q.back_face_deg = (p.back_face_deg + turn).clamp(25.0, 75.0);
            if (q.back_face_deg - p.back_face_deg).abs() < 10.0 {
                q.back_face_deg = p.back_face_deg - turn;
            }
        }
        _ => {
            let turn = rng.uniform(10.0, 20.0);
            q.front_face_deg = p.front_face_deg - turn;
        }
    }
    q
}

/// A random sub-window of a real SEM frame from `crops` (half to all of one, 4:3),
/// flipped at random, resized to `width` x `height`: the adversarial suite's real-SEM
/// frames, which show no probe at all.
pub fn real_window(crops: &[GrayImage], width: u32, height: u32, rng: &mut Rng) -> GrayImage {
    let crop = &crops[rng.int(0, crops.len() as u32 - 1) as usize];
    let (cw, ch) = crop.dimensions();
    let share = rng.uniform(0.5, 1.0);
    let w = ((cw as f64 * share) as u32).min(ch * 4 / 3).max(64);
    let h = (w * 3 / 4).min(ch);
    let x = rng.int(0, cw - w);
    let y = rng.int(0, ch - h);
    let mut window = image::imageops::crop_imm(crop, x, y, w, h).to_image();
    if rng.chance(0.5) {
        image::imageops::flip_horizontal_in_place(&mut window);
    }
    if rng.chance(0.5) {
        image::imageops::flip_vertical_in_place(&mut window);
    }
    image::imageops::resize(
        &window,
        width,
        height,
        image::imageops::FilterType::Triangle,
    )
}
