//! Canny edges on the detection image, restricted to the bright candidate regions.
//!
//! Non-maximum suppression across the gradient, then hysteresis (seeds above a high
//! threshold grow along pixels above a low one), with both thresholds set from the
//! measured gradient noise, so "strong edges only" means the same thing on a clean
//! frame and a noisy one. The grey-level threshold (fixed or Otsu) is applied as a mask:
//! an edge pixel is kept only if its bright side, a little way up the gradient, is at
//! least that bright. Every kept pixel remembers its sub-pixel position and gradient
//! direction, which is what lets the Hough stage check polarity.

use super::geometry::{nearest_pixel, truncate_index, wrap_pi};
use super::pyramid::Pyramid;
use super::simd::dispatch;

/// Hysteresis thresholds in units of the gradient noise.
const HIGH_SIGMAS: f32 = 5.0;
const LOW_SIGMAS: f32 = 2.5;
/// How far up the gradient (detection pixels) the bright side is sampled.
const BRIGHT_SIDE_PX: f32 = 2.0;

/// One edge pixel of the detection image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgePoint {
    /// Sub-pixel position (detection-image coordinates).
    pub x: f32,
    pub y: f32,
    /// Image angle of the gradient, pointing towards the brighter side, radians.
    pub angle: f32,
    /// The gradient's unit vector (cos, sin of `angle`).
    pub ux: f32,
    pub uy: f32,
    pub mag: f32,
}

impl EdgePoint {
    /// Cosine of the angle between the gradient and a unit normal: cheaper than angles.
    #[inline]
    pub fn alignment(&self, normal: [f64; 2]) -> f64 {
        self.ux as f64 * normal[0] + self.uy as f64 * normal[1]
    }
}

/// Edge pixels of one frame, plus a per-pixel map of their gradient directions.
#[derive(Debug, Default)]
pub struct EdgeMap {
    pub width: usize,
    pub height: usize,
    pub points: Vec<EdgePoint>,
    /// 0 where there is no edge, else 1 + the gradient direction quantised to 255 steps.
    pub direction: Vec<u8>,
    /// Gradient noise (grey levels per detection pixel) the thresholds were set from.
    pub noise: f32,
    state: Vec<u8>,
    stack: Vec<u32>,
    /// Pixels that survived suppression (weak or strong), in scan order.
    marked: Vec<u32>,
}

const NONE: u8 = 0;
const WEAK: u8 = 1;
const STRONG: u8 = 2;

/// Quantises an image angle for [`EdgeMap::direction`].
pub fn direction_code(angle: f32) -> u8 {
    let turns = (angle / std::f32::consts::TAU).rem_euclid(1.0);
    1 + ((turns * 255.0) as u8).min(254)
}

/// Image angle (radians) of a direction code.
pub fn code_angle(code: u8) -> f32 {
    ((code - 1) as f32 + 0.5) / 255.0 * std::f32::consts::TAU
}

impl EdgeMap {
    /// Finds the edges of `pyr` whose bright side reaches `threshold`.
    pub fn detect(&mut self, pyr: &Pyramid, threshold: f32) {
        let (w, h) = (pyr.width, pyr.height);
        self.width = w;
        self.height = h;
        self.state.clear();
        self.state.resize(w * h, NONE);
        self.direction.clear();
        self.direction.resize(w * h, 0);
        self.points.clear();
        self.marked.clear();
        self.stack.clear();
        // Room for the worst case (every pixel an edge), once per image size: after
        // that, no frame allocates whatever it shows.
        self.points.reserve(w * h);
        self.marked.reserve(w * h);
        self.stack.reserve(w * h);
        self.noise = pyr.gradient_noise();
        let high = HIGH_SIGMAS * self.noise;
        let low = LOW_SIGMAS * self.noise;
        suppress(self, pyr, [low, high], threshold);
        self.hysteresis();
        self.collect(pyr);
    }

    /// Non-maximum suppression and the bright-side mask; marks WEAK/STRONG candidates.
    /// Maxima are found [`RUN`] pixels at a time in vector arithmetic without branches
    /// (the noise of a harsh frame mispredicted them); only they are visited.
    #[inline(always)]
    fn suppress(&mut self, pyr: &Pyramid, low: f32, high: f32, threshold: f32) {
        let w = self.width;
        for y in 3..self.height.saturating_sub(3) {
            let end = y * w + w.saturating_sub(3);
            let mut i = y * w + 3;
            let mut x = 3;
            while i < end {
                let mut found = if i + RUN <= end {
                    maxima(pyr, i, low)
                } else {
                    (0..end - i).fold(0, |f, l| f | (maximum(pyr, i + l, low) as u64) << (8 * l))
                };
                while found != 0 {
                    let l = found.trailing_zeros() as usize / 8;
                    found &= found - 1;
                    self.mark(pyr, [x + l, y], high, threshold);
                }
                i += RUN;
                x += RUN;
            }
        }
    }

    /// Marks local maximum `[x, y]` WEAK or STRONG if its bright side reaches
    /// `threshold`.
    #[inline(always)]
    fn mark(&mut self, pyr: &Pyramid, [x, y]: [usize; 2], high: f32, threshold: f32) {
        let (w, h) = (self.width, self.height);
        let i = y * w + x;
        let m = pyr.mag[i];
        let (ux, uy) = (pyr.gx[i] / m, pyr.gy[i] / m);
        // x, y >= 3 > BRIGHT_SIDE_PX: truncating after +0.5 rounds.
        let bx = truncate_index(x as f32 + BRIGHT_SIDE_PX * ux + 0.5);
        let by = truncate_index(y as f32 + BRIGHT_SIDE_PX * uy + 0.5);
        if pyr.grey[by.min(h - 1) * w + bx.min(w - 1)] < threshold {
            return;
        }
        self.marked.push(i as u32);
        if m >= high {
            self.state[i] = STRONG;
            self.stack.push(i as u32);
        } else {
            self.state[i] = WEAK;
        }
    }

    /// Grows STRONG pixels into connected WEAK ones; whatever stays WEAK is dropped.
    fn hysteresis(&mut self) {
        let w = self.width;
        while let Some(i) = self.stack.pop() {
            let i = i as usize;
            for off in [-(w as isize) - 1, -(w as isize), -(w as isize) + 1, -1, 1] {
                for j in [i as isize + off, i as isize - off] {
                    let j = j as usize;
                    if self.state[j] == WEAK {
                        self.state[j] = STRONG;
                        self.stack.push(j as u32);
                    }
                }
            }
        }
    }

    /// Lists the STRONG pixels with a sub-pixel position across the edge.
    fn collect(&mut self, pyr: &Pyramid) {
        let w = self.width;
        for k in 0..self.marked.len() {
            let i = self.marked[k] as usize;
            if self.state[i] != STRONG {
                continue;
            }
            let (x, y) = (i % w, i / w);
            let (gx, gy, m) = (pyr.gx[i], pyr.gy[i], pyr.mag[i]);
            let (dx, dy) = neighbour_step(gx, gy);
            let ahead = pyr.mag[(i as isize + dy * w as isize + dx) as usize];
            let behind = pyr.mag[(i as isize - dy * w as isize - dx) as usize];
            let curvature = behind - 2.0 * m + ahead;
            let offset = if curvature < 0.0 {
                (0.5 * (behind - ahead) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            let angle = fast_atan2(gy, gx);
            self.direction[i] = direction_code(angle);
            self.points.push(EdgePoint {
                x: x as f32 + offset * dx as f32,
                y: y as f32 + offset * dy as f32,
                angle,
                ux: gx / m,
                uy: gy / m,
                mag: m,
            });
        }
    }
}

/// [`EdgeMap::suppress`] (`limits`: low and high) as one function, for [`suppress`].
#[inline(always)]
fn suppress_body(map: &mut EdgeMap, pyr: &Pyramid, limits: [f32; 2], threshold: f32) {
    map.suppress(pyr, limits[0], limits[1], threshold);
}

dispatch! {
    /// [`suppress_body`], with AVX2 when the CPU has it (see `vision::simd`).
    fn suppress(map: &mut EdgeMap, pyr: &Pyramid, limits: [f32; 2], threshold: f32)
        => suppress_body
}

impl EdgeMap {
    /// Whether an edge pixel whose gradient is within `tol` of `normal_angle` lies within
    /// a pixel of `p` across the line of unit normal `normal`.
    pub fn supports(&self, p: [f64; 2], normal: [f64; 2], normal_angle: f64, tol: f64) -> bool {
        for k in [-1.0, 0.0, 1.0] {
            let q = [p[0] + k * normal[0], p[1] + k * normal[1]];
            let Some(i) = nearest_pixel(q, self.width, self.height) else {
                continue;
            };
            let code = self.direction[i];
            if code != 0 && wrap_pi(code_angle(code) as f64 - normal_angle).abs() < tol {
                return true;
            }
        }
        false
    }
}

/// atan2 to about 1e-5 rad (a polynomial on one octant): the libm call was a tenth of
/// the edge stage, and the Hough stage needs the direction to a degree.
pub fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (num, den) = if ax >= ay { (ay, ax) } else { (ax, ay) };
    if den == 0.0 {
        return 0.0;
    }
    let t = num / den;
    let t2 = t * t;
    // Minimax polynomial for atan on [0, 1].
    let mut a = t
        * (0.999_866_f32
            + t2 * (-0.330_299_5 + t2 * (0.180_141 + t2 * (-0.085_133 + t2 * 0.020_835_1))));
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// Pixels [`maxima`] tests at once.
const RUN: usize = 8;

/// Byte `l` is 1 when pixel `i + l` is a maximum (see [`maximum`]), for `l < RUN`.
// Lane loops are indexed on purpose: that is the shape the vectoriser recognises.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn maxima(pyr: &Pyramid, i: usize, low: f32) -> u64 {
    let w = pyr.width;
    // Three rows of magnitudes, one pixel wider than the run on either side, and the
    // run's gradient: five range checks per run instead of one per neighbour.
    let around = |k: usize| -> &[f32; RUN + 2] {
        pyr.mag[k - 1..k + RUN + 1]
            .try_into()
            .expect("a slice of RUN + 2")
    };
    let run = |v: &[f32]| -> [f32; RUN] { v[i..i + RUN].try_into().expect("a slice of RUN") };
    let (up, mid, down) = (around(i - w), around(i), around(i + w));
    let (gx, gy) = (run(&pyr.gx), run(&pyr.gy));
    let mut found = [false; RUN];
    for l in 0..RUN {
        // east, west, south, north, south-east, north-west, north-east, south-west
        let near = [
            mid[l + 2],
            mid[l],
            down[l + 1],
            up[l + 1],
            down[l + 2],
            up[l],
            up[l + 2],
            down[l],
        ];
        found[l] = is_maximum(mid[l + 1], gx[l], gy[l], near, low);
    }
    u64::from_le_bytes(found.map(u8::from))
}

/// Whether pixel `i` is at least `low` and a maximum across its gradient (not below
/// the neighbour ahead, above the one behind).
#[inline(always)]
fn maximum(pyr: &Pyramid, i: usize, low: f32) -> bool {
    let (w, mag) = (pyr.width, &pyr.mag);
    let around = [
        mag[i + 1],
        mag[i - 1],
        mag[i + w],
        mag[i - w],
        mag[i + w + 1],
        mag[i - w - 1],
        mag[i + 1 - w],
        mag[i + w - 1],
    ];
    is_maximum(mag[i], pyr.gx[i], pyr.gy[i], around, low)
}

/// [`maximum`] of a magnitude `m`, gradient (`gx`, `gy`) and the magnitudes `around`
/// (east, west, south, north, south-east, north-west, north-east, south-west), without
/// branches: the pair across the gradient is the one [`neighbour_step`] picks.
#[inline(always)]
fn is_maximum(m: f32, gx: f32, gy: f32, around: [f32; 8], low: f32) -> bool {
    let [e, west, s, n, se, nw, ne, sw] = around;
    let (ax, ay) = (gx.abs(), gy.abs());
    // neighbour_step's four cases as exclusive flags; every comparison is made and the
    // flags pick one pair (choices between loaded values would become branches).
    let h = ay <= 0.4142 * ax;
    let v = !h & (ax <= 0.4142 * ay);
    let d = !h & !v & ((gx > 0.0) == (gy > 0.0));
    let a = !h & !v & !d;
    // Magnitudes are never NaN: the negation of the scan's `m < low`, then of
    // `m < ahead || m <= behind`.
    (m >= low)
        & ((h & (m >= e) & (m > west))
            | (v & (m >= s) & (m > n))
            | (d & (m >= se) & (m > nw))
            | (a & (m >= ne) & (m > sw)))
}

/// The 8-neighbour step closest to the gradient direction.
fn neighbour_step(gx: f32, gy: f32) -> (isize, isize) {
    // tan(22.5 deg) = 0.4142
    let (ax, ay) = (gx.abs(), gy.abs());
    if ay <= 0.4142 * ax {
        (1, 0)
    } else if ax <= 0.4142 * ay {
        (0, 1)
    } else if (gx > 0.0) == (gy > 0.0) {
        (1, 1)
    } else {
        (1, -1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, Luma};

    #[test]
    fn a_bright_disc_gives_a_ring_of_inward_gradients() {
        let frame = GrayImage::from_fn(640, 480, |x, y| {
            let r = ((x as f32 - 320.0).powi(2) + (y as f32 - 240.0).powi(2)).sqrt();
            Luma([if r < 100.0 { 200 } else { 60 }])
        });
        let mut pyr = Pyramid::default();
        pyr.build(&frame);
        let mut edges = EdgeMap::default();
        edges.detect(&pyr, 130.0);
        assert!(edges.points.len() > 250, "{}", edges.points.len());
        for p in &edges.points {
            let (cx, cy) = (159.75, 119.75);
            let r = ((p.x - cx).powi(2) + (p.y - cy).powi(2)).sqrt();
            assert!((r - 50.0).abs() < 1.5, "{r}");
            let inward = (cy - p.y).atan2(cx - p.x);
            let diff = (p.angle - inward).rem_euclid(std::f32::consts::TAU);
            assert!(
                !(0.1..=std::f32::consts::TAU - 0.1).contains(&diff),
                "{diff}"
            );
        }
        // Nothing passes a mask brighter than the disc.
        edges.detect(&pyr, 230.0);
        assert!(edges.points.is_empty());
    }

    #[test]
    fn fast_atan2_matches_the_library() {
        for i in 0..3600 {
            let a = (i as f32 / 10.0 - 180.0).to_radians();
            for r in [0.3f32, 1.0, 250.0] {
                let (y, x) = (r * a.sin(), r * a.cos());
                let err = (fast_atan2(y, x) - y.atan2(x)).abs();
                let err = err.min((err - std::f32::consts::TAU).abs());
                assert!(err < 2e-5, "{a} {err}");
            }
        }
    }

    #[test]
    fn direction_codes_round_trip() {
        for a in [-3.0f32, -1.0, 0.0, 0.5, 3.1] {
            let back = code_angle(direction_code(a));
            let diff = (back - a).rem_euclid(std::f32::consts::TAU);
            assert!(diff.min(std::f32::consts::TAU - diff) < 0.013, "{a} {back}");
        }
    }
}
