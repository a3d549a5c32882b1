//! One station of an edge: the grey levels across the predicted line, averaged along a
//! short run parallel to it, and where (and by how much) they step with the edge's
//! polarity.
//!
//! The profile is read at half-pixel spacing across the line; each sample averages
//! [`RUN`] bilinear reads one pixel apart along it, which cuts the noise by about
//! `sqrt(RUN)` while a pose within a degree moves the run's ends by a few hundredths
//! of a pixel (four samples are read at a time with AVX2 gathers where the CPU has
//! them, to the bit as one at a time). The step is found at the largest signed
//! derivative over one pixel either side; its size is the mean level on the probe's
//! side minus the mean outside, both read clear of the blur, and it is placed by its
//! area between them (unbiased for any symmetric blur, where a derivative peak of
//! interpolated samples leans toward the pixel centres by up to 0.15 px).

use image::GrayImage;

use crate::vision::geometry::{add, along, bilinear_inside, inside_centres, scale};

/// Samples averaged along the edge per profile point, one pixel apart.
pub(super) const RUN: usize = 7;
/// Profile spacing across the edge, pixels.
const DT: f64 = 0.5;
/// The derivative spans this many samples either side (one pixel).
const HALF_SPAN: usize = 2;
/// The levels either side of a located step are read this far from it, pixels: past
/// the blur of an SEM beam (sigma up to 1.6 px) and within the thinnest body.
const LEVEL_NEAR: f64 = 2.5;
const LEVEL_FAR: f64 = 4.5;

/// A step found at one station.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Located {
    /// Where the step lies along the inward normal from the station, pixels.
    pub t: f64,
    /// Inside minus outside level, times the edge's polarity: positive when the frame
    /// steps as the edge does.
    pub step: f64,
    /// Mean level on the probe's side.
    pub inside: f64,
}

/// Reads stations; keeps its profile buffer between calls.
#[derive(Debug, Default)]
pub struct Stations {
    profile: Vec<f64>,
}

impl Stations {
    /// The step of polarity `polarity` nearest in strength to the edge's, within
    /// `reach` pixels of `at` along the inward unit normal `normal` (with `reach` 0,
    /// the step read centred on `at`). `None` when the profile leaves the frame.
    pub fn locate(
        &mut self,
        frame: &GrayImage,
        at: [f64; 2],
        normal: [f64; 2],
        polarity: f64,
        reach: f64,
    ) -> Option<Located> {
        let tangent = along(normal);
        let lo = -(reach + LEVEL_FAR);
        let count = (2.0 * (reach + LEVEL_FAR) / DT).round() as usize + 1;
        self.profile.clear();
        if !read_profile(frame, at, normal, tangent, lo, count, &mut self.profile) {
            return None;
        }
        let p = &self.profile;
        let d = |i: usize| polarity * (p[i + HALF_SPAN] - p[i - HALF_SPAN]);
        let first = ((LEVEL_FAR / DT) as usize).max(HALF_SPAN + 1);
        let last = (count - 1 - first).max(first);
        let mut best = first;
        for i in first..=last {
            if d(i) > d(best) {
                best = i;
            }
        }
        let peak = lo + best as f64 * DT;
        let mean = |from: f64, to: f64| {
            let (i0, i1) = (
                ((from - lo) / DT).round().max(0.0) as usize,
                (((to - lo) / DT).round() as usize).min(count - 1),
            );
            p[i0..=i1].iter().sum::<f64>() / (i1 + 1 - i0) as f64
        };
        let inside = mean(peak + LEVEL_NEAR, peak + LEVEL_FAR);
        let outside = mean(peak - LEVEL_FAR, peak - LEVEL_NEAR);
        // The step's position by its area: for an ideal step at e between the two
        // levels, the integral of (inside - level) / (inside - outside) from a to b is
        // e - a, whatever the (symmetric) blur and wherever the samples fall.
        let rise = inside - outside;
        let half = (LEVEL_NEAR / DT) as usize;
        let (i0, i1) = (best - half, (best + half).min(count - 1));
        let t = if rise.abs() > 1e-9 {
            let mut area = 0.0;
            for (i, &level) in p.iter().enumerate().take(i1 + 1).skip(i0) {
                let edge_weight = if i == i0 || i == i1 { 0.5 } else { 1.0 };
                area += edge_weight * ((inside - level) / rise).clamp(0.0, 1.0);
            }
            lo + i0 as f64 * DT + area * DT
        } else {
            peak
        };
        Some(Located {
            t,
            step: polarity * (inside - outside),
            inside,
        })
    }
}

/// The sample `j` along the edge of profile point `i` (see [`read_profile`]).
#[inline(always)]
fn sample_at(
    at: [f64; 2],
    normal: [f64; 2],
    tangent: [f64; 2],
    lo: f64,
    i: usize,
    j: usize,
) -> [f64; 2] {
    let centre = add(at, scale(normal, lo + i as f64 * DT));
    add(centre, scale(tangent, j as f64 - (RUN / 2) as f64))
}

/// Fills `profile` with `count` points across the line through `at`, from `lo` along
/// `normal` at [`DT`] spacing, each the mean of [`RUN`] bilinear reads one pixel apart
/// along `tangent`; false (and `profile` unfilled) when a read would leave the frame's
/// pixel centres.
fn read_profile(
    frame: &GrayImage,
    at: [f64; 2],
    normal: [f64; 2],
    tangent: [f64; 2],
    lo: f64,
    count: usize,
    profile: &mut Vec<f64>,
) -> bool {
    let read = |i: usize, j: usize| sample_at(at, normal, tangent, lo, i, j);
    // The samples fill a parallelogram: inside the frame when its corners are.
    let corners =
        [(0, 0), (0, RUN - 1), (count - 1, 0), (count - 1, RUN - 1)].map(|(i, j)| read(i, j));
    if !corners.iter().all(|&c| inside_centres(frame, c)) {
        return false;
    }
    profile.resize(count, 0.0);
    #[cfg(target_arch = "x86_64")]
    if crate::vision::simd::avx2() && gather_safe(frame, &corners) {
        // SAFETY: the CPU runs AVX2 (asked at run time), and every four-byte read of
        // the gathers lies in the frame ([`gather_safe`]).
        unsafe { gathered::read_profile(frame, at, normal, tangent, lo, profile) };
        return true;
    }
    for (i, level) in profile.iter_mut().enumerate() {
        let sum: f64 = (0..RUN).map(|j| bilinear_inside(frame, read(i, j))).sum();
        *level = sum / RUN as f64;
    }
    true
}

/// Whether every read of a profile with these corners keeps the gathers' four-byte
/// loads (a pixel, its right neighbour and two more, on its row and the one below)
/// inside the frame: the corners four columns or more from the right and two rows or
/// more from the bottom (the reads between them stray from the corners' hull by
/// rounding only, far less than a pixel), and every byte's index an `i32`.
#[cfg(target_arch = "x86_64")]
fn gather_safe(frame: &GrayImage, corners: &[[f64; 2]; 4]) -> bool {
    let (w, h) = (f64::from(frame.width()), f64::from(frame.height()));
    i32::try_from(frame.as_raw().len()).is_ok()
        && corners.iter().all(|c| c[0] <= w - 5.0 && c[1] <= h - 3.0)
}

/// The profile read four points at a time with AVX2 gathers, to the bit as the scalar
/// loop reads it: the same operations in the same order on each lane, no fused
/// multiply-add.
#[cfg(target_arch = "x86_64")]
mod gathered {
    use std::arch::x86_64::*;

    use image::GrayImage;

    use super::{DT, RUN};

    /// The profile of [`super::read_profile`] into `profile` (its length the count).
    ///
    /// # Safety
    /// The CPU runs AVX2, and [`super::gather_safe`] holds for the profile's corners.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn read_profile(
        frame: &GrayImage,
        at: [f64; 2],
        normal: [f64; 2],
        tangent: [f64; 2],
        lo: f64,
        profile: &mut [f64],
    ) {
        let count = profile.len();
        let raw: *const i32 = frame.as_raw().as_ptr().cast();
        let row = _mm_set1_epi32(frame.width() as i32);
        let byte = _mm_set1_epi32(0xff);
        let (atx, aty) = (_mm256_set1_pd(at[0]), _mm256_set1_pd(at[1]));
        let (nx, ny) = (_mm256_set1_pd(normal[0]), _mm256_set1_pd(normal[1]));
        let (tx, ty) = (_mm256_set1_pd(tangent[0]), _mm256_set1_pd(tangent[1]));
        // A gathered word's first two bytes: a pixel and its right neighbour.
        let left = |word: __m128i| _mm256_cvtepi32_pd(_mm_and_si128(word, byte));
        let right =
            |word: __m128i| _mm256_cvtepi32_pd(_mm_and_si128(_mm_srli_epi32::<8>(word), byte));
        for first in (0..count).step_by(4) {
            // Four profile points; past the end, the last one again (not stored).
            let point = |k: usize| lo + (first + k).min(count - 1) as f64 * DT;
            let offset = _mm256_setr_pd(point(0), point(1), point(2), point(3));
            let cx = _mm256_add_pd(atx, _mm256_mul_pd(nx, offset));
            let cy = _mm256_add_pd(aty, _mm256_mul_pd(ny, offset));
            let mut sum = _mm256_setzero_pd();
            for j in 0..RUN {
                let d = _mm256_set1_pd(j as f64 - (RUN / 2) as f64);
                let x = _mm256_add_pd(cx, _mm256_mul_pd(tx, d));
                let y = _mm256_add_pd(cy, _mm256_mul_pd(ty, d));
                let (x0, y0) = (_mm256_cvttpd_epi32(x), _mm256_cvttpd_epi32(y));
                let fx = _mm256_sub_pd(x, _mm256_cvtepi32_pd(x0));
                let fy = _mm256_sub_pd(y, _mm256_cvtepi32_pd(y0));
                let index = _mm_add_epi32(_mm_mullo_epi32(y0, row), x0);
                let upper = _mm_i32gather_epi32::<1>(raw, index);
                let lower = _mm_i32gather_epi32::<1>(raw, _mm_add_epi32(index, row));
                let (v00, v10) = (left(upper), right(upper));
                let (v01, v11) = (left(lower), right(lower));
                let top = _mm256_add_pd(v00, _mm256_mul_pd(fx, _mm256_sub_pd(v10, v00)));
                let bottom = _mm256_add_pd(v01, _mm256_mul_pd(fx, _mm256_sub_pd(v11, v01)));
                let level = _mm256_add_pd(top, _mm256_mul_pd(fy, _mm256_sub_pd(bottom, top)));
                sum = _mm256_add_pd(sum, level);
            }
            let mut out = [0.0; 4];
            _mm256_storeu_pd(
                out.as_mut_ptr(),
                _mm256_div_pd(sum, _mm256_set1_pd(RUN as f64)),
            );
            let n = (count - first).min(4);
            profile[first..first + n].copy_from_slice(&out[..n]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame bright (200) right of x = 40.3 and dark (50) left of it, blurred as an
    /// SEM beam does (a Gaussian of 1 px).
    fn step_frame() -> GrayImage {
        GrayImage::from_fn(96, 64, |x, _| {
            let v = 0.5 * (1.0 + erf((f64::from(x) - 40.3) / std::f64::consts::SQRT_2));
            image::Luma([(50.0 + 150.0 * v).round() as u8])
        })
    }

    /// The error function (Abramowitz and Stegun 7.1.26, to 1.5e-7).
    fn erf(x: f64) -> f64 {
        let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
        let poly = t
            * (0.254_829_592
                + t * (-0.284_496_736
                    + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
        (1.0 - poly * (-x * x).exp()).copysign(x)
    }

    #[test]
    fn a_step_is_placed_to_a_tenth_of_a_pixel_with_its_size_and_sign() {
        let frame = step_frame();
        let mut stations = Stations::default();
        let found = stations
            .locate(&frame, [38.0, 30.0], [1.0, 0.0], 1.0, 5.0)
            .unwrap();
        assert!((found.t - 2.3).abs() < 0.1, "{found:?}");
        assert!((found.step - 150.0).abs() < 15.0, "{found:?}");
        let wrong = stations
            .locate(&frame, [38.0, 30.0], [1.0, 0.0], -1.0, 5.0)
            .unwrap();
        assert!(wrong.step < 10.0, "{wrong:?}");
        assert!(stations
            .locate(&frame, [2.0, 30.0], [1.0, 0.0], 1.0, 5.0)
            .is_none());
    }
}
