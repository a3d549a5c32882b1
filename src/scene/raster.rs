//! Exact anti-aliased polygon coverage: for every pixel, the area of the pixel's unit
//! square that lies inside a polygon (non-zero winding). Signed areas of the polygon's
//! edges are accumulated into a row buffer and prefix-summed, the algorithm of font
//! rasterisers (font-rs), so the cost is the perimeter plus the covered pixels.
//!
//! Coordinates are in pixels with the origin at the top-left pixel's centre
//! (docs/conventions.md):
//! pixel (i, j) is the square [i - 1/2, i + 1/2] x [j - 1/2, j + 1/2]. Polygons may
//! extend far outside the frame; they are clipped to it exactly.

/// Reusable buffers for filling polygons into a frame of a fixed size.
#[derive(Debug, Default)]
pub struct Rasterizer {
    width: usize,
    height: usize,
    /// Signed area deltas, (width + 2) per row.
    acc: Vec<f32>,
    /// Per row, the first and one-past-last touched column (empty when first >= last).
    span: Vec<(u32, u32)>,
    clip_a: Vec<[f64; 2]>,
    clip_b: Vec<[f64; 2]>,
}

impl Rasterizer {
    /// Sizes the buffers for a frame (allocates only when the size grows).
    pub fn resize(&mut self, width: u32, height: u32) {
        self.width = width as usize;
        self.height = height as usize;
        let stride = self.width + 2;
        self.acc.clear();
        self.acc.resize(stride * self.height, 0.0);
        self.span.clear();
        self.span.resize(self.height, (u32::MAX, 0));
        // Clipping adds at most two vertices per clip line; room for long outlines.
        let vertices = 8 * (self.width + self.height) + 8;
        for v in [&mut self.clip_a, &mut self.clip_b] {
            v.reserve(vertices.saturating_sub(v.len()));
        }
    }

    /// Fills `polygon` (vertices in pixel coordinates, implicitly closed) and calls
    /// `paint(x, y, coverage)` for every pixel with coverage > 0, row by row.
    pub fn fill(&mut self, polygon: &[[f64; 2]], mut paint: impl FnMut(usize, usize, f32)) {
        if polygon.len() < 3 || self.width == 0 || self.height == 0 {
            return;
        }
        self.clip(polygon);
        let points = std::mem::take(&mut self.clip_a);
        let n = points.len();
        for i in 0..n {
            let p = points[i];
            let q = points[(i + 1) % n];
            self.line(p, q);
        }
        self.clip_a = points;
        self.sweep(&mut paint);
    }

    /// Clips to the frame's columns [-1/2, width - 1/2] (exactly: area left or right of
    /// the frame does not matter, but must not wrap) and shifts to corner coordinates,
    /// where pixel (i, j) is [i, i + 1] x [j, j + 1]. Rows are clipped while sweeping.
    fn clip(&mut self, polygon: &[[f64; 2]]) {
        self.clip_a.clear();
        self.clip_a
            .extend(polygon.iter().map(|p| [p[0] + 0.5, p[1] + 0.5]));
        let w = self.width as f64;
        clip_half_plane(&self.clip_a, &mut self.clip_b, |p| p[0], 0.0);
        clip_half_plane(&self.clip_b, &mut self.clip_a, |p| -p[0], -w);
    }

    /// Accumulates the signed area of one edge (corner coordinates, x within [0, width]).
    fn line(&mut self, p: [f64; 2], q: [f64; 2]) {
        if p[1] == q[1] {
            return;
        }
        let (dir, p0, p1) = if p[1] < q[1] {
            (1.0, p, q)
        } else {
            (-1.0, q, p)
        };
        let h = self.height as f64;
        if p1[1] <= 0.0 || p0[1] >= h {
            return;
        }
        let dxdy = (p1[0] - p0[0]) / (p1[1] - p0[1]);
        let y_start = p0[1].max(0.0);
        let y_end = p1[1].min(h);
        let mut x = p0[0] + (y_start - p0[1]) * dxdy;
        let stride = self.width + 2;
        let max_x = self.width as f64;
        let mut row = y_start.floor() as usize;
        while (row as f64) < y_end && row < self.height {
            let top = (row as f64).max(y_start);
            let bottom = ((row + 1) as f64).min(y_end);
            let dy = bottom - top;
            let x_next = (x + dxdy * dy).clamp(0.0, max_x);
            let d = dy * dir;
            let line = &mut self.acc[row * stride..(row + 1) * stride];
            let (lo, hi) = deposit(line, x.clamp(0.0, max_x), x_next, d);
            let span = &mut self.span[row];
            span.0 = span.0.min(lo as u32);
            span.1 = span.1.max(hi as u32 + 1);
            x = x_next;
            row += 1;
        }
    }

    /// Prefix-sums each touched row into coverage, hands it out and clears the buffer.
    fn sweep(&mut self, paint: &mut impl FnMut(usize, usize, f32)) {
        let stride = self.width + 2;
        for y in 0..self.height {
            let (first, last) = self.span[y];
            if first >= last {
                continue;
            }
            self.span[y] = (u32::MAX, 0);
            let line = &mut self.acc[y * stride..(y + 1) * stride];
            let mut sum = 0.0f32;
            for (x, cell) in line
                .iter_mut()
                .enumerate()
                .take(last as usize)
                .skip(first as usize)
            {
                sum += *cell;
                *cell = 0.0;
                let coverage = sum.abs().min(1.0);
                if coverage > 1e-6 && x < self.width {
                    paint(x, y, coverage);
                }
            }
        }
    }
}

/// Deposits the signed area of a segment crossing one row from x0 to x1 (height `d`),
/// returning the first and last touched cells.
fn deposit(line: &mut [f32], x_from: f64, x_to: f64, d: f64) -> (usize, usize) {
    let (x0, x1) = if x_from < x_to {
        (x_from, x_to)
    } else {
        (x_to, x_from)
    };
    let x0_floor = x0.floor();
    let x0i = x0_floor as usize;
    let x1_ceil = x1.ceil();
    let x1i = x1_ceil as usize;
    if x1i <= x0i + 1 {
        // Within one cell: the area right of the segment's midpoint goes to the next cell.
        let xm = 0.5 * (x_from + x_to) - x0_floor;
        line[x0i] += (d - d * xm) as f32;
        line[x0i + 1] += (d * xm) as f32;
        return (x0i, x0i + 1);
    }
    let s = 1.0 / (x1 - x0);
    let x0f = x0 - x0_floor;
    let a0 = 0.5 * s * (1.0 - x0f) * (1.0 - x0f);
    let x1f = x1 - x1_ceil + 1.0;
    let am = 0.5 * s * x1f * x1f;
    line[x0i] += (d * a0) as f32;
    if x1i == x0i + 2 {
        line[x0i + 1] += (d * (1.0 - a0 - am)) as f32;
    } else {
        let a1 = s * (1.5 - x0f);
        line[x0i + 1] += (d * (a1 - a0)) as f32;
        for cell in &mut line[x0i + 2..x1i - 1] {
            *cell += (d * s) as f32;
        }
        let a2 = a1 + (x1i - x0i - 3) as f64 * s;
        line[x1i - 1] += (d * (1.0 - a2 - am)) as f32;
    }
    line[x1i] += (d * am) as f32;
    (x0i, x1i)
}

/// Sutherland-Hodgman: keeps the part of `input` where `key(p) >= bound`.
fn clip_half_plane(
    input: &[[f64; 2]],
    output: &mut Vec<[f64; 2]>,
    key: impl Fn(&[f64; 2]) -> f64,
    bound: f64,
) {
    output.clear();
    let n = input.len();
    for i in 0..n {
        let p = input[i];
        let q = input[(i + 1) % n];
        let (kp, kq) = (key(&p) - bound, key(&q) - bound);
        if kp >= 0.0 {
            output.push(p);
        }
        if (kp >= 0.0) != (kq >= 0.0) {
            let t = kp / (kp - kq);
            output.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn coverage(width: u32, height: u32, polygon: &[[f64; 2]]) -> Vec<f32> {
        let mut r = Rasterizer::default();
        r.resize(width, height);
        let mut out = vec![0.0f32; (width * height) as usize];
        r.fill(polygon, |x, y, c| out[y * width as usize + x] = c);
        out
    }

    /// Slow reference: supersampled point-in-polygon (even-odd) per pixel.
    fn reference(width: u32, height: u32, polygon: &[[f64; 2]], n: usize) -> Vec<f32> {
        let inside = |px: f64, py: f64| {
            let mut c = false;
            for i in 0..polygon.len() {
                let a = polygon[i];
                let b = polygon[(i + 1) % polygon.len()];
                if (a[1] > py) != (b[1] > py)
                    && px < a[0] + (py - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
                {
                    c = !c;
                }
            }
            c
        };
        let mut out = vec![0.0f32; (width * height) as usize];
        for y in 0..height as usize {
            for x in 0..width as usize {
                let mut hits = 0;
                for j in 0..n {
                    for i in 0..n {
                        let px = x as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                        let py = y as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                        hits += usize::from(inside(px, py));
                    }
                }
                out[y * width as usize + x] = hits as f32 / (n * n) as f32;
            }
        }
        out
    }

    #[test]
    fn total_coverage_is_the_polygon_area() {
        let tri = [[3.2, 2.7], [17.9, 5.1], [8.4, 14.6]];
        let cov = coverage(24, 20, &tri);
        let area = 0.5
            * ((tri[1][0] - tri[0][0]) * (tri[2][1] - tri[0][1])
                - (tri[2][0] - tri[0][0]) * (tri[1][1] - tri[0][1]))
                .abs();
        let sum: f64 = cov.iter().map(|&c| f64::from(c)).sum();
        assert!((sum - area).abs() < 1e-4, "sum {sum} area {area}");
    }

    #[test]
    fn matches_supersampled_reference() {
        let poly = [
            [2.3, 1.1],
            [14.7, 3.9],
            [12.2, 9.4],
            [7.5, 6.6],
            [3.1, 11.8],
        ];
        let fast = coverage(18, 14, &poly);
        let slow = reference(18, 14, &poly, 64);
        for (a, b) in fast.iter().zip(&slow) {
            assert!((a - b).abs() < 0.02, "{a} vs {b}");
        }
    }

    #[test]
    fn half_plane_edge_has_exact_subpixel_position() {
        // Left of x = 4.3 is inside: pixel 4 spans [3.5, 4.5] and is 80% covered.
        let poly = [[-50.0, -50.0], [4.3, -50.0], [4.3, 60.0], [-50.0, 60.0]];
        let cov = coverage(10, 6, &poly);
        for y in 0..6 {
            let row = &cov[y * 10..(y + 1) * 10];
            assert!((row[3] - 1.0).abs() < 1e-6);
            assert!((row[4] - 0.8).abs() < 1e-5, "{}", row[4]);
            assert_eq!(row[5], 0.0);
        }
    }

    #[test]
    fn polygons_far_outside_the_frame_are_clipped() {
        let poly = [[-1e5, -1e5], [1e5, -1e5], [1e5, 2.5], [-1e5, 2.5]];
        let cov = coverage(8, 6, &poly);
        let sum: f32 = cov.iter().sum();
        assert!((sum - 8.0 * 3.0).abs() < 1e-3, "{sum}");
        let none = coverage(8, 6, &[[20.0, 1.0], [30.0, 1.0], [25.0, 5.0]]);
        assert!(none.iter().all(|&c| c == 0.0));
    }
}
