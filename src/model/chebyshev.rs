//! Piecewise Chebyshev interpolation on a uniform mesh: `F` smooth functions of one
//! variable sampled together at the Chebyshev points of the first kind of each piece,
//! evaluated with Clenshaw's recurrence. The lookup table ([`super::table`]) is two of
//! these; locating a piece is one multiplication, so a lookup costs a few dozen flops.

/// Polynomial degree in each piece (DEGREE + 1 samples per piece).
pub(crate) const DEGREE: usize = 12;
const NODES: usize = DEGREE + 1;

/// `F` functions interpolated piecewise on [start, start + pieces * width].
#[derive(Debug, Clone)]
pub(crate) struct Piecewise<const F: usize> {
    start: f64,
    /// 2 / width: maps a piece onto [-1, 1].
    scale: f64,
    last_piece: usize,
    /// Chebyshev coefficients of each piece, c_0 halved, lowest degree first.
    coefficients: Vec<[[f64; F]; NODES]>,
}

impl<const F: usize> Piecewise<F> {
    /// Samples `f` at NODES points in each of `pieces` equal pieces of [start, end]
    /// (never at a piece's ends, so `f` may be singular at `start` or `end`).
    pub(crate) fn build(
        start: f64,
        end: f64,
        pieces: usize,
        mut f: impl FnMut(f64) -> [f64; F],
    ) -> Self {
        let pieces = pieces.max(1);
        let width = (end - start) / pieces as f64;
        let angle =
            |i: usize, k: usize| std::f64::consts::PI * k as f64 * (i as f64 + 0.5) / NODES as f64;
        // cosines[i][k] = cos(k theta_i) = T_k(t_i) at the node t_i = cos(theta_i).
        let mut cosines = [[0.0; NODES]; NODES];
        for (i, row) in cosines.iter_mut().enumerate() {
            for (k, value) in row.iter_mut().enumerate() {
                *value = angle(i, k).cos();
            }
        }
        let mut coefficients = Vec::with_capacity(pieces);
        for piece in 0..pieces {
            let centre = start + (piece as f64 + 0.5) * width;
            let samples: [[f64; F]; NODES] =
                std::array::from_fn(|i| f(centre + 0.5 * width * cosines[i][1]));
            let mut c = [[0.0; F]; NODES];
            for (k, ck) in c.iter_mut().enumerate() {
                for (sample, row) in samples.iter().zip(&cosines) {
                    for (cf, value) in ck.iter_mut().zip(sample) {
                        *cf += value * row[k];
                    }
                }
                let weight = if k == 0 { 1.0 } else { 2.0 } / NODES as f64;
                ck.iter_mut().for_each(|cf| *cf *= weight);
            }
            coefficients.push(c);
        }
        Piecewise {
            start,
            scale: 2.0 / width,
            last_piece: pieces - 1,
            coefficients,
        }
    }

    /// The interpolants at `x`, which the caller keeps within [start, end].
    #[inline]
    pub(crate) fn eval(&self, x: f64) -> [f64; F] {
        let u = (x - self.start) * self.scale;
        // `as usize` saturates (negative -> 0); the clamp keeps `end` in the last piece.
        let piece = ((u * 0.5) as usize).min(self.last_piece);
        let t = u - (2 * piece + 1) as f64;
        let c = &self.coefficients[piece];
        let (mut b1, mut b2) = ([0.0; F], [0.0; F]);
        for ck in c[1..].iter().rev() {
            let b0: [f64; F] = std::array::from_fn(|m| ck[m] + 2.0 * t * b1[m] - b2[m]);
            b2 = b1;
            b1 = b0;
        }
        std::array::from_fn(|m| c[0][m] + t * b1[m] - b2[m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_smooth_functions_to_rounding() {
        let table = Piecewise::build(0.0, 3.0, 20, |x| [x.exp(), (5.0 * x).sin()]);
        for i in 0..=3000 {
            let x = 3.0 * i as f64 / 3000.0;
            let [e, s] = table.eval(x);
            assert!((e / x.exp() - 1.0).abs() < 4e-15, "exp at {x}: {e}");
            // 5x itself rounds by up to 1 ulp of 15, i.e. 1.8e-15.
            assert!((s - (5.0 * x).sin()).abs() < 1e-14, "sin at {x}: {s}");
        }
    }

    #[test]
    fn polynomials_up_to_the_degree_are_exact() {
        let p = |x: f64| (0..=DEGREE).fold(0.0, |acc, k| acc * x + (k as f64 - 5.5));
        let table = Piecewise::build(-1.0, 2.0, 1, |x| [p(x)]);
        let xs = (0..=300).map(|i| -1.0 + 3.0 * i as f64 / 300.0);
        let largest = xs.clone().map(|x| p(x).abs()).fold(0.0, f64::max);
        for x in xs {
            let err = (table.eval(x)[0] - p(x)).abs();
            assert!(
                err < 1e-14 * largest,
                "at {x}: error {err:e} of {largest:e}"
            );
        }
    }
}
