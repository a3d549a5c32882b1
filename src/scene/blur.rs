//! Separable Gaussian blur of an f32 frame (the SEM's beam spot), with edge pixels
//! replicated beyond the border. Two passes of a normalised kernel of radius
//! ceil(3 sigma), each accumulating blocks of 16 outputs in registers so it vectorises.

/// Reusable kernel and scratch row for blurring frames of any size.
#[derive(Debug, Default)]
pub struct Blur {
    kernel: Vec<f32>,
    scratch: Vec<f32>,
    padded: Vec<f32>,
}

impl Blur {
    /// Blurs `image` (row-major, `width` x `height`) in place with standard deviation
    /// `sigma_px`; sigma <= 0 leaves it untouched.
    pub fn apply(&mut self, image: &mut [f32], width: usize, height: usize, sigma_px: f64) {
        if sigma_px <= 0.0 || width == 0 || height == 0 {
            return;
        }
        self.make_kernel(sigma_px);
        self.horizontal(image, width, height);
        self.vertical(image, width, height);
    }

    /// Reserves room for rows `width` wide and blurs up to `max_sigma_px`, so that later
    /// calls within those bounds do not allocate.
    pub fn reserve(&mut self, width: usize, max_sigma_px: f64) {
        let radius = (3.0 * max_sigma_px).ceil().max(1.0) as usize;
        let grow = |v: &mut Vec<f32>, n: usize| v.reserve(n.saturating_sub(v.len()));
        grow(&mut self.kernel, 2 * radius + 1);
        grow(&mut self.padded, width + 2 * radius);
        grow(&mut self.scratch, (radius + 1) * width);
    }

    fn make_kernel(&mut self, sigma: f64) {
        let radius = (3.0 * sigma).ceil().max(1.0) as i64;
        self.kernel.clear();
        let weights = (-radius..=radius).map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp());
        let total: f64 = weights.clone().sum();
        self.kernel.extend(weights.map(|w| (w / total) as f32));
    }

    fn horizontal(&mut self, image: &mut [f32], width: usize, height: usize) {
        let radius = self.kernel.len() / 2;
        self.padded.resize(width + 2 * radius, 0.0);
        for y in 0..height {
            let row = &mut image[y * width..(y + 1) * width];
            let (first, last) = (row[0], row[width - 1]);
            self.padded[..radius].fill(first);
            self.padded[radius..radius + width].copy_from_slice(row);
            self.padded[radius + width..].fill(last);
            let padded = &self.padded;
            convolve_blocks(row, &self.kernel, |k, x| &padded[x + k..]);
        }
    }

    fn vertical(&mut self, image: &mut [f32], width: usize, height: usize) {
        let radius = self.kernel.len() / 2;
        // Output rows go to a ring of (radius + 1) rows so that the inputs they need are
        // still intact; `scratch` holds that ring.
        let ring = radius + 1;
        self.scratch.resize(ring * width, 0.0);
        for y in 0..height + ring {
            if y >= ring {
                let done = y - ring;
                let slot = done % ring;
                image[done * width..(done + 1) * width]
                    .copy_from_slice(&self.scratch[slot * width..(slot + 1) * width]);
            }
            if y >= height {
                continue;
            }
            let slot = y % ring;
            let out = &mut self.scratch[slot * width..(slot + 1) * width];
            let source = &*image;
            convolve_blocks(out, &self.kernel, |k, x| {
                let src = (y + k).saturating_sub(radius).min(height - 1);
                &source[src * width + x..(src + 1) * width]
            });
        }
    }
}

/// Block width of the convolution: the accumulators stay in registers.
const BLOCK: usize = 16;

/// `out[x] = sum_k kernel[k] * tap(k, x)[0]` for every x, where `tap(k, x)` is the input
/// slice seen by tap k at output x. Accumulates a block of outputs over all taps at a
/// time so the sums stay in registers and the inner loop vectorises.
fn convolve_blocks<'a>(out: &mut [f32], kernel: &[f32], tap: impl Fn(usize, usize) -> &'a [f32]) {
    let width = out.len();
    let mut x = 0;
    while x + BLOCK <= width {
        let mut acc = [0.0f32; BLOCK];
        for (k, &weight) in kernel.iter().enumerate() {
            let src = &tap(k, x)[..BLOCK];
            for (a, &v) in acc.iter_mut().zip(src) {
                *a += weight * v;
            }
        }
        out[x..x + BLOCK].copy_from_slice(&acc);
        x += BLOCK;
    }
    for (i, o) in out.iter_mut().enumerate().skip(x) {
        *o = kernel
            .iter()
            .enumerate()
            .map(|(k, &w)| w * tap(k, i)[0])
            .sum();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn preserves_a_constant_image() {
        let mut img = vec![42.0f32; 30 * 20];
        Blur::default().apply(&mut img, 30, 20, 1.3);
        assert!(img.iter().all(|&v| (v - 42.0).abs() < 1e-4));
    }

    #[test]
    fn impulse_response_is_a_normalised_gaussian_with_the_right_sigma() {
        let (w, h) = (41usize, 41usize);
        let mut img = vec![0.0f32; w * h];
        img[20 * w + 20] = 1.0;
        Blur::default().apply(&mut img, w, h, 1.6);
        let total: f64 = img.iter().map(|&v| f64::from(v)).sum();
        assert!((total - 1.0).abs() < 1e-5);
        let var_x: f64 = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(img[y * w + x]) * (x as f64 - 20.0).powi(2))
            .sum();
        assert!((var_x.sqrt() - 1.6).abs() < 0.01, "sigma {}", var_x.sqrt());
        // Separable and symmetric: transposed pixels agree.
        assert!((img[18 * w + 23] - img[23 * w + 18]).abs() < 1e-7);
    }

    #[test]
    fn vertical_pass_matches_direct_convolution() {
        let (w, h) = (3usize, 25usize);
        let mut img: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32).collect();
        let orig = img.clone();
        let mut blur = Blur::default();
        blur.make_kernel(1.2);
        blur.vertical(&mut img, w, h);
        let r = blur.kernel.len() / 2;
        for y in 0..h {
            for x in 0..w {
                let direct: f32 = (0..blur.kernel.len())
                    .map(|k| {
                        let src = (y + k).saturating_sub(r).min(h - 1);
                        blur.kernel[k] * orig[src * w + x]
                    })
                    .sum();
                assert!((img[y * w + x] - direct).abs() < 1e-4);
            }
        }
    }
}
