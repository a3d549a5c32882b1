//! One station of an edge: the grey levels across the predicted line, averaged along a
//! short run parallel to it, and where (and by how much) they step with the edge's
//! polarity.
//!
//! The profile is read at half-pixel spacing across the line; each sample averages
//! [`RUN`] bilinear reads one pixel apart along it, which cuts the noise by about
//! `sqrt(RUN)` while a pose within a degree moves the run's ends by a few hundredths
//! of a pixel. The step is found at the largest signed derivative over one pixel
//! either side; its size is the mean level on the probe's side minus the mean outside,
//! both read clear of the blur, and it is placed by its area between them (unbiased
//! for any symmetric blur, where a derivative peak of interpolated samples leans
//! toward the pixel centres by up to 0.15 px).

use image::GrayImage;

use crate::vision::geometry::{add, along, bilinear, scale};

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
        let half = (RUN / 2) as f64;
        for i in 0..count {
            let centre = add(at, scale(normal, lo + i as f64 * DT));
            let mut sum = 0.0;
            for j in 0..RUN {
                sum += bilinear(frame, add(centre, scale(tangent, j as f64 - half)))?;
            }
            self.profile.push(sum / RUN as f64);
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
