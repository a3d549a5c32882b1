//! The coarse detection image: the frame binned k x k (k chosen so the detection image
//! is about 320 pixels wide whatever the frame size), its histogram threshold, and its
//! smoothed gradient.
//!
//! Binning cuts the cost of every detection stage by k^2 and the noise by k; the
//! gradient is a 5x5 separable derivative-of-binomial (Sobel on a [1 2 1]-smoothed
//! image), normalised to grey levels per binned pixel. Full resolution is used again
//! only along the edges that detection finds (see `refine`).

use image::GrayImage;

use super::geometry::truncate_index;
use super::options::Threshold;
use super::simd::dispatch;

/// Target width of the detection image, pixels.
const DETECTION_WIDTH: u32 = 320;

/// A binned frame and its gradient, reused from frame to frame.
#[derive(Debug)]
pub struct Pyramid {
    /// Binning factor: one detection pixel covers `factor x factor` frame pixels.
    pub factor: u32,
    pub width: usize,
    pub height: usize,
    /// Mean grey level of each bin.
    pub grey: Vec<f32>,
    /// Gradient components, grey levels per detection pixel; zero on a 2-pixel border.
    pub gx: Vec<f32>,
    pub gy: Vec<f32>,
    pub mag: Vec<f32>,
    scratch_a: Vec<f32>,
    scratch_b: Vec<f32>,
    /// Histogram of `grey` (integer levels).
    histogram: [u32; 256],
    /// Width the buffers were last laid out for.
    width_seen: usize,
}

/// Rows of the horizontal pass kept for the vertical one.
const RING: usize = 5;

impl Default for Pyramid {
    fn default() -> Self {
        Pyramid {
            factor: 1,
            width: 0,
            height: 0,
            grey: Vec::new(),
            gx: Vec::new(),
            gy: Vec::new(),
            mag: Vec::new(),
            scratch_a: Vec::new(),
            scratch_b: Vec::new(),
            histogram: [0; 256],
            width_seen: 0,
        }
    }
}

/// The binning factor used for a frame `width` pixels wide.
pub fn binning_factor(width: u32) -> u32 {
    (width / DETECTION_WIDTH).max(1)
}

/// Frame coordinates of the centre of pixel (x, y) of a detection image binned
/// `factor x factor`.
pub fn to_frame(factor: u32, p: [f64; 2]) -> [f64; 2] {
    let k = factor as f64;
    [k * p[0] + 0.5 * (k - 1.0), k * p[1] + 0.5 * (k - 1.0)]
}

impl Pyramid {
    /// Bins `frame` and computes its gradient. Allocates only when the size changes.
    pub fn build(&mut self, frame: &GrayImage) {
        self.build_binned(frame, binning_factor(frame.width()));
    }

    /// As [`Pyramid::build`], binned `factor x factor`.
    pub fn build_binned(&mut self, frame: &GrayImage, factor: u32) {
        let width = (frame.width() / factor) as usize;
        let height = (frame.height() / factor) as usize;
        self.factor = factor;
        self.width = width;
        self.height = height;
        let resized = width * height != self.grey.len() || width != self.width_seen;
        self.width_seen = width;
        for buf in [&mut self.grey, &mut self.gx, &mut self.gy, &mut self.mag] {
            if resized {
                // The gradient leaves a two-pixel border untouched: it must read zero.
                buf.clear();
            }
            buf.resize(width * height, 0.0);
        }
        self.scratch_a.resize(RING * width, 0.0);
        self.scratch_b.resize(RING * width, 0.0);
        bin_into(
            frame,
            factor as usize,
            width,
            height,
            &mut self.grey,
            &mut self.histogram,
        );
        gradient(self);
    }

    /// Frame coordinates of the centre of detection pixel (x, y).
    pub fn to_frame(&self, p: [f64; 2]) -> [f64; 2] {
        to_frame(self.factor, p)
    }

    /// Detection-image coordinates of frame point `p`.
    pub fn frame_to_detection(&self, p: [f64; 2]) -> [f64; 2] {
        let k = self.factor as f64;
        [(p[0] - 0.5 * (k - 1.0)) / k, (p[1] - 0.5 * (k - 1.0)) / k]
    }

    /// The grey level separating bright candidate regions from the rest, on the binned
    /// image: the configured level, or Otsu's threshold of its histogram.
    pub fn threshold(&self, threshold: Threshold) -> f32 {
        match threshold {
            Threshold::Level(level) => level as f32,
            Threshold::Otsu => otsu(&self.histogram) as f32 + 0.5,
        }
    }

    /// Robust estimate of the gradient-magnitude noise: the median magnitude of a
    /// pure-noise gradient is 1.1774 times the per-component standard deviation, and
    /// most of a frame is flat.
    pub fn gradient_noise(&self) -> f32 {
        let mut hist = [0u32; 512];
        let bin = 0.25f32;
        // Every sixth pixel: the median of ~13k magnitudes is stable to a percent.
        let mut n = 0u32;
        for &m in self.mag.iter().step_by(6) {
            // Magnitudes are finite and non-negative: clamping before the truncation
            // gives the bin that truncating and then clamping gives.
            hist[truncate_index((m * (1.0 / bin)).min(511.0))] += 1;
            n += 1;
        }
        let half = n / 2;
        let mut acc = 0;
        for (i, &h) in hist.iter().enumerate() {
            acc += h;
            if acc >= half {
                return ((i as f32 + 0.5) * bin / 1.1774).max(0.25);
            }
        }
        511.0 * bin
    }

    /// Horizontal pass of row `y` into its slot of the five-row ring: derivative
    /// [-1 -2 0 2 1] and smoothing [1 4 6 4 1]. (Shifted slices zipped together
    /// vectorise; windows() does not. The ring keeps the pass in the L1 cache.)
    #[inline(always)]
    fn horizontal(&mut self, y: usize) {
        let w = self.width;
        let row = &self.grey[y * w..(y + 1) * w];
        let n = w - 4;
        let (a, b, c, d, e) = (
            &row[..n],
            &row[1..n + 1],
            &row[2..n + 2],
            &row[3..n + 3],
            &row[4..],
        );
        let slot = (y % RING) * w;
        let dx = &mut self.scratch_a[slot + 2..slot + 2 + n];
        for ((((o, &a), &b), &d), &e) in dx.iter_mut().zip(a).zip(b).zip(d).zip(e) {
            *o = 2.0 * (d - b) + (e - a);
        }
        let sx = &mut self.scratch_b[slot + 2..slot + 2 + n];
        for (((((o, &a), &b), &c), &d), &e) in sx.iter_mut().zip(a).zip(b).zip(c).zip(d).zip(e) {
            *o = a + e + 4.0 * (b + d) + 6.0 * c;
        }
    }

    /// Vertical pass for row `y` from the ring rows `y - 2 ..= y + 2`; `norm` makes both
    /// components grey levels per pixel.
    #[inline(always)]
    fn vertical(&mut self, y: usize, norm: f32) {
        let w = self.width;
        let row = |k: usize| ((y + k - 2) % RING) * w + 2..((y + k - 2) % RING) * w + w - 2;
        let (d, s) = (&self.scratch_a, &self.scratch_b);
        let (d0, d1, d2, d3, d4) = (&d[row(0)], &d[row(1)], &d[row(2)], &d[row(3)], &d[row(4)]);
        let (s0, s1, s3, s4) = (&s[row(0)], &s[row(1)], &s[row(3)], &s[row(4)]);
        let out = y * w + 2..(y + 1) * w - 2;
        let gx = &mut self.gx[out.clone()];
        for (((((o, &a), &b), &c), &dd), &e) in
            gx.iter_mut().zip(d0).zip(d1).zip(d2).zip(d3).zip(d4)
        {
            *o = (a + e + 4.0 * (b + dd) + 6.0 * c) * norm;
        }
        let gy = &mut self.gy[out.clone()];
        for ((((o, &a), &b), &dd), &e) in gy.iter_mut().zip(s0).zip(s1).zip(s3).zip(s4) {
            *o = (2.0 * (dd - b) + e - a) * norm;
        }
        let mag = &mut self.mag[out.clone()];
        for ((m, &x), &y) in mag.iter_mut().zip(&self.gx[out.clone()]).zip(&self.gy[out]) {
            *m = (x * x + y * y).sqrt();
        }
    }
}

/// The gradient of `pyr.grey` into `pyr.gx`, `gy`, `mag`, a row at a time.
#[inline(always)]
fn gradient_body(pyr: &mut Pyramid) {
    let (w, h) = (pyr.width, pyr.height);
    if w < 5 || h < 5 {
        return;
    }
    let norm = 1.0 / 128.0;
    for y in 0..h {
        pyr.horizontal(y);
        if y >= 4 {
            pyr.vertical(y - 2, norm);
        }
    }
}

dispatch! {
    /// [`gradient_body`], with AVX2 when the CPU has it (see `vision::simd`).
    fn gradient(pyr: &mut Pyramid) => gradient_body
}

dispatch! {
    /// [`bin_body`], with AVX2 when the CPU has it (see `vision::simd`).
    fn bin_into(
        frame: &GrayImage,
        factor: usize,
        width: usize,
        height: usize,
        out: &mut [f32],
        hist: &mut [u32; 256],
    ) => bin_body
}

/// Largest binning factor whose column sums fit the `u16` columns (255 x 257 < 2^16).
const MAX_COLUMN_FACTOR: usize = 257;

/// Bits of the fixed-point reciprocal that divides a bin's sum by `factor^2` for the
/// histogram: the sum `s` of d = `factor^2` 8-bit levels times `ceil(2^48 / d)`, shifted
/// down by 48, is `s / d` plus less than `255 d / 2^48`, under the `1 / d` that would
/// carry it to the next integer while `255 d^2 < 2^48` (a division costs a dozen
/// multiplications).
const RECIPROCAL_BITS: u32 = 48;
/// Largest binning factor the reciprocal divides exactly (see [`RECIPROCAL_BITS`]).
const MAX_RECIPROCAL_FACTOR: usize = 1023;

/// The sums of each run of `K` consecutive `columns` into `sums` (a fixed run length
/// unrolls).
#[inline(always)]
fn column_runs<const K: usize>(sums: &mut [u32], columns: &[u16]) {
    for (s, c) in sums.iter_mut().zip(columns.chunks_exact(K)) {
        let run: &[u16; K] = c.try_into().expect("chunks of K");
        *s = run.iter().map(|&v| v as u32).sum::<u32>();
    }
}

/// Mean of each `factor x factor` block of `frame` into `out` (row-major, `width` wide).
/// Also fills `hist` with the histogram of the binned grey levels (for Otsu).
#[inline(always)]
fn bin_body(
    frame: &GrayImage,
    factor: usize,
    width: usize,
    height: usize,
    out: &mut [f32],
    hist: &mut [u32; 256],
) {
    let mut partial = [[0u32; 256]; 4];
    let shift = (factor * factor).trailing_zeros();
    let power_of_two = (factor * factor).is_power_of_two();
    let reciprocal = factor <= MAX_RECIPROCAL_FACTOR;
    let inverse = (1u64 << RECIPROCAL_BITS).div_ceil((factor * factor) as u64);
    let stride = frame.width() as usize;
    let raw: &[u8] = frame.as_raw();
    let inv = 1.0 / (factor * factor) as f32;
    let mut sums = [0u32; 1024];
    debug_assert!(width <= sums.len());
    let sums = &mut sums[..width];
    let mut columns = [0u16; 2048];
    for by in 0..height {
        if factor == 2 {
            // The common case in one pass over both rows.
            let r0 = &raw[2 * by * stride..][..2 * width];
            let r1 = &raw[(2 * by + 1) * stride..][..2 * width];
            // Columns first (vectorises), then pairs of columns.
            let columns = &mut columns[..2 * width];
            for ((c, &a), &b) in columns.iter_mut().zip(r0).zip(r1) {
                *c = a as u16 + b as u16;
            }
            for (s, c) in sums.iter_mut().zip(columns.chunks_exact(2)) {
                *s = (c[0] + c[1]) as u32;
            }
        } else if factor <= MAX_COLUMN_FACTOR && width * factor <= columns.len() {
            // Columns first (the rows added element-wise vectorise), then runs of
            // `factor` columns.
            let columns = &mut columns[..width * factor];
            columns.iter_mut().for_each(|c| *c = 0);
            for dy in 0..factor {
                let row = &raw[(by * factor + dy) * stride..][..width * factor];
                for (c, &v) in columns.iter_mut().zip(row) {
                    *c += v as u16;
                }
            }
            // The factors of 1024- and 1280-wide frames, unrolled.
            match factor {
                3 => column_runs::<3>(sums, columns),
                4 => column_runs::<4>(sums, columns),
                _ => {
                    for (s, c) in sums.iter_mut().zip(columns.chunks_exact(factor)) {
                        *s = c.iter().map(|&v| v as u32).sum::<u32>();
                    }
                }
            }
        } else {
            sums.iter_mut().for_each(|s| *s = 0);
            for dy in 0..factor {
                let row = &raw[(by * factor + dy) * stride..][..width * factor];
                for (s, px) in sums.iter_mut().zip(row.chunks_exact(factor)) {
                    *s += px.iter().map(|&v| v as u32).sum::<u32>();
                }
            }
        }
        for (o, &s) in out[by * width..(by + 1) * width]
            .iter_mut()
            .zip(sums.iter())
        {
            *o = s as f32 * inv;
        }
        // Four histograms taken in turn: consecutive pixels of one level no longer wait
        // on each other's increment.
        let level = |s: u32| {
            let level = if power_of_two {
                s >> shift
            } else if reciprocal {
                ((s as u64 * inverse) >> RECIPROCAL_BITS) as u32
            } else {
                s / (factor * factor) as u32
            };
            // A mean of 8-bit levels is at most 255 already: the mask only lets the
            // compiler drop the bounds check.
            (level & 255) as usize
        };
        let quads = sums.chunks_exact(4);
        for &s in quads.remainder() {
            partial[0][level(s)] += 1;
        }
        for quad in quads {
            for (h, &s) in partial.iter_mut().zip(quad) {
                h[level(s)] += 1;
            }
        }
    }
    for (i, h) in hist.iter_mut().enumerate() {
        *h = partial.iter().map(|p| p[i]).sum();
    }
}

/// Otsu's threshold of a 256-bin histogram: the level maximising the between-class
/// variance (pixels `<= level` form the dark class).
pub fn otsu(hist: &[u32; 256]) -> u8 {
    // At most 254: the bright class is never empty.
    otsu_from(hist, 0) as u8
}

/// Otsu's threshold over the grey levels from `from` up: the level at or above `from`
/// maximising the between-class variance of those levels (`from` when no level splits
/// them, 254 at most).
pub fn otsu_from(hist: &[u32; 256], from: usize) -> usize {
    let total: f64 = hist[from..].iter().map(|&h| h as f64).sum();
    let sum_all: f64 = (from..256).map(|i| i as f64 * hist[i] as f64).sum();
    let (mut w0, mut sum0, mut best, mut best_level) = (0.0, 0.0, -1.0, from);
    for (level, &h) in hist.iter().enumerate().skip(from) {
        w0 += h as f64;
        sum0 += level as f64 * h as f64;
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let diff = sum0 / w0 - (sum_all - sum0) / w1;
        let between = w0 * w1 * diff * diff;
        if between > best {
            best = between;
            best_level = level;
        }
    }
    best_level.min(254)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn otsu_splits_two_modes() {
        let mut hist = [0u32; 256];
        hist[60] = 1000;
        hist[61] = 800;
        hist[200] = 300;
        let t = otsu(&hist);
        assert!((61..200).contains(&t), "{t}");
    }

    #[test]
    fn otsu_from_splits_only_the_levels_from_it_up() {
        let mut hist = [0u32; 256];
        hist[60] = 900;
        hist[150] = 300;
        hist[220] = 100;
        let all = otsu_from(&hist, 0);
        assert!((60..150).contains(&all), "{all}");
        let bright = otsu_from(&hist, all + 1);
        assert!((150..220).contains(&bright), "{bright}");
        // Nothing to split from 221 up: the level asked from.
        assert_eq!(otsu_from(&hist, 221), 221);
    }

    #[test]
    fn gradient_of_a_ramp_is_its_slope() {
        // Grey level 3 per frame pixel along x: 6 per detection pixel at factor 2.
        let frame = GrayImage::from_fn(640, 480, |x, _| image::Luma([(x as f32 * 0.3) as u8]));
        let mut p = Pyramid::default();
        p.build(&frame);
        assert_eq!((p.factor, p.width, p.height), (2, 320, 240));
        let i = 100 * p.width + 100;
        assert!((p.gx[i] - 0.6).abs() < 0.05, "{}", p.gx[i]);
        assert!(p.gy[i].abs() < 1e-4);
        // Detection pixel 100 covers frame pixels 200 and 201: centre 200.5.
        assert_eq!(p.to_frame([100.0, 0.0])[0], 200.5);
        assert_eq!(p.frame_to_detection([200.5, 0.5]), [100.0, 0.0]);
    }

    #[test]
    fn binning_gives_each_block_mean_and_its_histogram() {
        let frame = GrayImage::from_fn(200, 150, |x, y| {
            image::Luma([((x * 37 + y * 101 + x * y) % 256) as u8])
        });
        let mut p = Pyramid::default();
        for factor in 1..=7u32 {
            p.build_binned(&frame, factor);
            let mut hist = [0u32; 256];
            for by in 0..p.height as u32 {
                for bx in 0..p.width as u32 {
                    let mut sum = 0;
                    for dy in 0..factor {
                        for dx in 0..factor {
                            sum += frame.get_pixel(bx * factor + dx, by * factor + dy)[0] as u32;
                        }
                    }
                    let i = by as usize * p.width + bx as usize;
                    assert_eq!(p.grey[i], sum as f32 * (1.0 / (factor * factor) as f32));
                    hist[(sum / (factor * factor)) as usize] += 1;
                }
            }
            assert_eq!(p.histogram, hist, "factor {factor}");
        }
    }

    #[test]
    fn large_frames_bin_to_the_same_detection_size() {
        assert_eq!(binning_factor(1280), 4);
        assert_eq!(binning_factor(640), 2);
        assert_eq!(binning_factor(300), 1);
    }
}
