//! Plane geometry shared by the tracker: oriented lines, rotations and the one place
//! where internal angles meet the screen convention.
//!
//! Internally every angle is an *image* angle: `atan2(dy, dx)` in pixel coordinates
//! (x right, y down), so a positive image rotation turns clockwise on screen. Outputs
//! follow docs/conventions.md (degrees, counter-clockwise on screen), converted only by
//! [`screen_deg_from_image_rad`] and, in the tests, `image_rad_from_screen_deg`.

/// Screen angle (degrees, CCW on screen) of an image-angle rotation (radians, y down).
pub fn screen_deg_from_image_rad(angle_rad: f64) -> f64 {
    -angle_rad.to_degrees()
}

/// Image angle (radians, y down) of a screen angle (degrees, CCW on screen).
#[cfg(test)]
pub fn image_rad_from_screen_deg(angle_deg: f64) -> f64 {
    -angle_deg.to_radians()
}

/// `v` truncated to an index, for a `v` known to be non-negative and below 2^31 (a
/// pixel, a bin). Through i32: a float-to-usize cast costs a dozen instructions more
/// to saturate, and these run in the tracker's hot loops.
#[inline(always)]
pub fn truncate_index(v: f32) -> usize {
    v as i32 as usize
}

/// The row-major index of the pixel nearest `p` in an image `width` x `height`, if it
/// lies inside. Rounded by truncating the shifted coordinates, non-negative once
/// checked: `f64::round` is a libm call on x86-64, and this runs for every pixel the
/// tracker samples along a line.
#[inline(always)]
pub fn nearest_pixel(p: [f64; 2], width: usize, height: usize) -> Option<usize> {
    let (x, y) = (p[0] + 0.5, p[1] + 0.5);
    if !(x >= 0.0 && y >= 0.0 && x < width as f64 && y < height as f64) {
        return None;
    }
    Some(y as usize * width + x as usize)
}

/// Wraps an angle to (-pi, pi]. Inputs are differences of angles, a turn or two at
/// most, so a loop beats the remainder (a libm call).
pub fn wrap_pi(angle_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    if !angle_rad.is_finite() {
        return angle_rad;
    }
    let mut a = angle_rad;
    while a > PI {
        a -= TAU;
    }
    while a <= -PI {
        a += TAU;
    }
    a
}

/// Unit vector at an image angle.
pub fn unit(angle_rad: f64) -> [f64; 2] {
    [angle_rad.cos(), angle_rad.sin()]
}

/// The principal axis of points (total least squares): their centroid, the axis's
/// image angle, and the points' summed squared distance from the centroid.
pub fn principal_axis(pts: &[[f64; 2]]) -> ([f64; 2], f64, f64) {
    let n = pts.len() as f64;
    let c = [
        pts.iter().map(|p| p[0]).sum::<f64>() / n,
        pts.iter().map(|p| p[1]).sum::<f64>() / n,
    ];
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    (c, 0.5 * (2.0 * sxy).atan2(sxx - syy), sxx + syy)
}

/// The mean of `read` over a strip reaching from `from` along the unit vector `dir`:
/// `rows` rows one pixel apart, each of `2 * half + 1` samples one pixel apart across
/// `dir`, centred on its axis; `None` when no sample reads (the strip out of the
/// frame).
pub fn strip_mean(
    from: [f64; 2],
    dir: [f64; 2],
    rows: usize,
    half: i32,
    read: impl Fn([f64; 2]) -> Option<f64>,
) -> Option<f64> {
    let side = [-dir[1], dir[0]];
    let (mut sum, mut n) = (0.0, 0usize);
    for d in 0..rows {
        for j in -half..=half {
            if let Some(v) = read(add(
                add(from, scale(dir, d as f64)),
                scale(side, f64::from(j)),
            )) {
                sum += v;
                n += 1;
            }
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// Bilinear grey level of `img` at `p`, `None` outside its pixel centres.
#[inline]
pub fn bilinear(img: &image::GrayImage, p: [f64; 2]) -> Option<f64> {
    inside_centres(img, p).then(|| bilinear_inside(img, p))
}

/// Whether `p` lies within `img`'s pixel centres (where [`bilinear_inside`] reads).
#[inline]
pub fn inside_centres(img: &image::GrayImage, p: [f64; 2]) -> bool {
    let (w, h) = (img.width(), img.height());
    w > 0
        && h > 0
        && p[0] >= 0.0
        && p[1] >= 0.0
        && p[0] <= f64::from(w - 1)
        && p[1] <= f64::from(h - 1)
}

/// Bilinear grey level of `img` at `p`, which must lie within its pixel centres
/// ([`inside_centres`]; outside, the read is clamped to the image, never out of it).
#[inline(always)]
pub fn bilinear_inside(img: &image::GrayImage, p: [f64; 2]) -> f64 {
    let (w, h) = (img.width() as usize, img.height() as usize);
    // Truncation is the floor for the non-negative coordinates inside.
    let (x0, y0) = ((p[0] as usize).min(w - 1), (p[1] as usize).min(h - 1));
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (p[0] - x0 as f64, p[1] - y0 as f64);
    let raw = img.as_raw();
    let v = |xx: usize, yy: usize| f64::from(raw[yy * w + xx]);
    let top = v(x0, y0) + fx * (v(x1, y0) - v(x0, y0));
    let bottom = v(x0, y1) + fx * (v(x1, y1) - v(x0, y1));
    top + fy * (bottom - top)
}

/// Rotates `v` by an image angle.
pub fn rotate(v: [f64; 2], angle_rad: f64) -> [f64; 2] {
    let (s, c) = angle_rad.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

pub fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

pub fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

pub fn add(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] + b[0], a[1] + b[1]]
}

pub fn scale(a: [f64; 2], k: f64) -> [f64; 2] {
    [a[0] * k, a[1] * k]
}

pub fn norm(a: [f64; 2]) -> f64 {
    (a[0] * a[0] + a[1] * a[1]).sqrt()
}

/// The direction along an edge whose inward normal is `normal`: the normal turned by
/// -90 degrees (image angle). Fixing it once keeps "along" coordinates consistent.
pub fn along(normal: [f64; 2]) -> [f64; 2] {
    [normal[1], -normal[0]]
}

/// An oriented line `normal . p = rho`; `normal` is unit and points into the probe
/// (towards the brighter side), so `normal . p - rho` is the signed depth of `p`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    pub normal: [f64; 2],
    pub rho: f64,
}

impl Line {
    /// The line through `point` with the given inward normal.
    pub fn through(point: [f64; 2], normal: [f64; 2]) -> Line {
        Line {
            normal,
            rho: dot(normal, point),
        }
    }

    /// Signed distance of `p`, positive on the inner (bright) side.
    pub fn depth(&self, p: [f64; 2]) -> f64 {
        dot(self.normal, p) - self.rho
    }

    /// Image angle of the inward normal.
    pub fn normal_angle(&self) -> f64 {
        self.normal[1].atan2(self.normal[0])
    }

    /// The point of the line closest to `p`.
    pub fn foot(&self, p: [f64; 2]) -> [f64; 2] {
        sub(p, scale(self.normal, self.depth(p)))
    }

    /// Intersection with another line; `None` when nearly parallel.
    pub fn intersect(&self, other: &Line) -> Option<[f64; 2]> {
        let det = self.normal[0] * other.normal[1] - self.normal[1] * other.normal[0];
        if det.abs() < 1e-9 {
            return None;
        }
        let x = (self.rho * other.normal[1] - self.normal[1] * other.rho) / det;
        let y = (self.normal[0] * other.rho - self.rho * other.normal[0]) / det;
        Some([x, y])
    }
}

/// The part of the line `origin + t * dir` inside the rectangle [lo, hi] (inclusive),
/// as a `t` interval, or `None` if it misses.
pub fn clip_to_rect(
    origin: [f64; 2],
    dir: [f64; 2],
    lo: [f64; 2],
    hi: [f64; 2],
) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for k in 0..2 {
        if dir[k].abs() < 1e-12 {
            if origin[k] < lo[k] || origin[k] > hi[k] {
                return None;
            }
            continue;
        }
        let a = (lo[k] - origin[k]) / dir[k];
        let b = (hi[k] - origin[k]) / dir[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn screen_convention_is_ccw_on_screen() {
        // A direction pointing right, turned by +10 deg on screen, points up-right:
        // dy < 0 in pixel coordinates.
        let d = rotate([1.0, 0.0], image_rad_from_screen_deg(10.0));
        assert!(d[0] > 0.98 && d[1] < -0.17 && d[1] > -0.18, "{d:?}");
        assert!((screen_deg_from_image_rad(image_rad_from_screen_deg(7.5)) - 7.5).abs() < 1e-12);
    }

    #[test]
    fn the_nearest_pixel_is_found_inside_the_image_only() {
        // 4 x 3: the nearest pixel rounds halves up, and within half a pixel of the
        // border a point is still inside.
        assert_eq!(nearest_pixel([1.49, 0.5], 4, 3), Some(4 + 1));
        assert_eq!(nearest_pixel([-0.49, 2.49], 4, 3), Some(2 * 4));
        assert_eq!(nearest_pixel([3.49, 0.0], 4, 3), Some(3));
        for outside in [[-0.51, 1.0], [3.5, 1.0], [1.0, 2.5], [f64::NAN, 1.0]] {
            assert_eq!(nearest_pixel(outside, 4, 3), None, "{outside:?}");
        }
    }

    #[test]
    fn line_intersection_and_depth() {
        let a = Line::through([3.0, 4.0], [1.0, 0.0]);
        let b = Line::through([3.0, 4.0], unit(1.0));
        let p = a.intersect(&b).unwrap();
        assert!((p[0] - 3.0).abs() < 1e-12 && (p[1] - 4.0).abs() < 1e-12);
        assert!((a.depth([5.0, 0.0]) - 2.0).abs() < 1e-12);
        assert!(a.intersect(&a).is_none());
        let f = b.foot([10.0, -3.0]);
        assert!(b.depth(f).abs() < 1e-12);
    }

    #[test]
    fn clipping_a_diagonal() {
        let (t0, t1) = clip_to_rect([0.0, 0.0], [1.0, 1.0], [0.0, 0.0], [9.0, 4.0]).unwrap();
        assert!((t0 - 0.0).abs() < 1e-12 && (t1 - 4.0).abs() < 1e-12);
        assert!(clip_to_rect([-5.0, 20.0], [1.0, 0.0], [0.0, 0.0], [9.0, 4.0]).is_none());
    }

    #[test]
    fn wrapping() {
        assert!((wrap_pi(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_pi(-0.5) + 0.5).abs() < 1e-12);
    }
}
