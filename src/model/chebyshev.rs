//! Piecewise Chebyshev interpolation: `F` smooth functions of one variable sampled
//! together at the Chebyshev points of the first kind of each piece. The lookup table
//! ([`super::table`]) uses two meshes: [`Uniform`] pieces, and [`Octaves`], a geometric
//! mesh whose piece is read off the float's exponent and leading mantissa bits (no
//! logarithm at lookup time).
//!
//! For speed each piece's Chebyshev series is turned into a polynomial in the piece's
//! local coordinate t in [-1, 1] at build time and evaluated with Estrin's scheme, whose
//! dependency chain is 4 multiply-adds deep instead of Clenshaw's or Horner's 12 (the
//! lookup is latency-bound). The series converge fast (coefficients fall by ~30 per
//! degree), so the monomial form loses nothing measurable on [-1, 1].

/// Polynomial degree in each piece (DEGREE + 1 samples per piece).
pub(crate) const DEGREE: usize = 12;
const NODES: usize = DEGREE + 1;
const _: () = assert!(
    DEGREE == 12,
    "Pieces::eval's Estrin scheme is written for degree 12"
);

/// One polynomial per piece, in the piece's local coordinate t in [-1, 1].
#[derive(Debug, Clone)]
struct Pieces<const F: usize> {
    /// Each piece's polynomial coefficients in t, lowest degree first.
    coefficients: Vec<[[f64; F]; NODES]>,
}

impl<const F: usize> Pieces<F> {
    /// Interpolates `f` on each interval [lo, hi] at NODES interior points.
    fn build(
        intervals: impl Iterator<Item = (f64, f64)>,
        mut f: impl FnMut(f64) -> [f64; F],
    ) -> Self {
        let cosines = chebyshev_at_nodes();
        let monomials = chebyshev_monomials();
        let coefficients = intervals
            .map(|(lo, hi)| {
                let (centre, half) = ((lo + hi) / 2.0, (hi - lo) / 2.0);
                let samples: [[f64; F]; NODES] =
                    std::array::from_fn(|i| f(centre + half * cosines[i][1]));
                let chebyshev = chebyshev_coefficients(&samples, &cosines);
                // a_j = sum_k c_k [t^j] T_k(t).
                std::array::from_fn(|j| {
                    std::array::from_fn(|m| {
                        (j..NODES).map(|k| chebyshev[k][m] * monomials[k][j]).sum()
                    })
                })
            })
            .collect();
        Pieces { coefficients }
    }

    fn last(&self) -> usize {
        self.coefficients.len().saturating_sub(1)
    }

    /// The interpolants of piece `piece` (<= [`Pieces::last`]) at local coordinate `t`.
    #[inline]
    fn eval(&self, piece: usize, t: f64) -> [f64; F] {
        let a = &self.coefficients[piece];
        let t2 = t * t;
        let t4 = t2 * t2;
        let t8 = t4 * t4;
        std::array::from_fn(|m| {
            let pair = |j: usize| a[j][m] + a[j + 1][m] * t;
            let r0 = pair(0) + pair(2) * t2;
            let r1 = pair(4) + pair(6) * t2;
            let r2 = pair(8) + pair(10) * t2;
            let s0 = r0 + r1 * t4;
            let s1 = r2 + a[12][m] * t4;
            s0 + s1 * t8
        })
    }
}

/// `F` functions interpolated on `pieces` equal pieces of [start, end].
#[derive(Debug, Clone)]
pub(crate) struct Uniform<const F: usize> {
    start: f64,
    /// 2 / width: maps a piece onto [-1, 1].
    scale: f64,
    pieces: Pieces<F>,
}

impl<const F: usize> Uniform<F> {
    /// Samples `f` at NODES interior points of each piece (never at a piece's ends, so
    /// `f` may be singular at `start` or `end`).
    pub(crate) fn build(
        start: f64,
        end: f64,
        pieces: usize,
        f: impl FnMut(f64) -> [f64; F],
    ) -> Self {
        let count = pieces.max(1);
        let width = (end - start) / count as f64;
        let intervals = (0..count).map(|i| {
            let lo = start + i as f64 * width;
            (lo, lo + width)
        });
        Uniform {
            start,
            scale: 2.0 / width,
            pieces: Pieces::build(intervals, f),
        }
    }

    /// The interpolants at `x`, which the caller keeps within [start, end].
    #[inline]
    pub(crate) fn eval(&self, x: f64) -> [f64; F] {
        let u = (x - self.start) * self.scale;
        // `as usize` saturates (negative and NaN -> 0); the clamp keeps `end` in the last
        // piece.
        let piece = ((u * 0.5) as usize).min(self.pieces.last());
        self.pieces.eval(piece, u - (2 * piece + 1) as f64)
    }
}

/// log2 of the pieces per octave in [`Octaves`].
const SUB_BITS: u32 = 2;
const SUB_PIECES: u64 = 1 << SUB_BITS;
const MANTISSA_BITS: u32 = 52;
const MANTISSA_MASK: u64 = (1 << MANTISSA_BITS) - 1;
/// The bits of 1.0: exponent 0, mantissa 0.
const ONE_BITS: u64 = 0x3FF << MANTISSA_BITS;

/// `F` functions interpolated on a geometric mesh of positive x: every octave
/// [2^e, 2^(e+1)] meeting [lo, hi] is cut into SUB_PIECES equal pieces. A piece's width is
/// at most 1/4 of its distance from 0, so a function singular at 0 converges equally fast
/// in every piece. Lookup reads the piece from the bits of x, with no logarithm.
#[derive(Debug, Clone)]
pub(crate) struct Octaves<const F: usize> {
    /// Biased exponent of the lowest octave.
    min_exponent: u64,
    pieces: Pieces<F>,
}

impl<const F: usize> Octaves<F> {
    /// Samples `f` on the whole octaves that cover [lo, hi] (0 < lo <= hi, normal floats),
    /// so `f` must accept x somewhat beyond them (below lo by up to half, above hi by up
    /// to twice).
    pub(crate) fn build(lo: f64, hi: f64, f: impl FnMut(f64) -> [f64; F]) -> Self {
        let min_exponent = lo.to_bits() >> MANTISSA_BITS;
        let max_exponent = hi.to_bits() >> MANTISSA_BITS;
        let intervals = (min_exponent..=max_exponent).flat_map(|biased| {
            let base = f64::from_bits(biased << MANTISSA_BITS);
            (0..SUB_PIECES).map(move |m| {
                let step = base / SUB_PIECES as f64;
                (base + m as f64 * step, base + (m + 1) as f64 * step)
            })
        });
        Octaves {
            min_exponent,
            pieces: Pieces::build(intervals, f),
        }
    }

    /// The interpolants at `x`, which the caller keeps within [lo, hi].
    #[inline]
    pub(crate) fn eval(&self, x: f64) -> [f64; F] {
        let bits = x.to_bits();
        // Octave and the leading SUB_BITS of the mantissa; out-of-range x lands in the
        // first or last piece instead of indexing out of bounds.
        let top = (bits >> (MANTISSA_BITS - SUB_BITS)).wrapping_sub(self.min_exponent << SUB_BITS);
        let piece = (top as usize).min(self.pieces.last());
        let sub = (top & (SUB_PIECES - 1)) as f64;
        // x / 2^e in [1, 2), exactly; then t in [-1, 1] within the sub-piece, exactly.
        let scaled = f64::from_bits((bits & MANTISSA_MASK) | ONE_BITS);
        let t = (scaled - 1.0) * (2 * SUB_PIECES) as f64 - (2.0 * sub + 1.0);
        self.pieces.eval(piece, t)
    }
}

/// `cosines[i][k]` = cos(k theta_i) = T_k(t_i) at the nodes t_i = cos(theta_i),
/// theta_i = pi (i + 1/2) / NODES.
fn chebyshev_at_nodes() -> [[f64; NODES]; NODES] {
    std::array::from_fn(|i| {
        std::array::from_fn(|k| {
            let theta = std::f64::consts::PI * (i as f64 + 0.5) / NODES as f64;
            (k as f64 * theta).cos()
        })
    })
}

/// Coefficients of the Chebyshev interpolant through `samples` at the nodes (the
/// discrete cosine transform), c_0 halved so that p = sum_k c_k T_k.
fn chebyshev_coefficients<const F: usize>(
    samples: &[[f64; F]; NODES],
    cosines: &[[f64; NODES]; NODES],
) -> [[f64; F]; NODES] {
    std::array::from_fn(|k| {
        let weight = if k == 0 { 1.0 } else { 2.0 } / NODES as f64;
        std::array::from_fn(|m| {
            let sum: f64 = samples
                .iter()
                .zip(cosines)
                .map(|(s, row)| s[m] * row[k])
                .sum();
            weight * sum
        })
    })
}

/// `monomials[k][j]` = coefficient of t^j in T_k(t) (exact small integers), from
/// T_{k+1} = 2 t T_k - T_{k-1}.
fn chebyshev_monomials() -> [[f64; NODES]; NODES] {
    let mut t = [[0.0; NODES]; NODES];
    t[0][0] = 1.0;
    t[1][1] = 1.0;
    for k in 1..DEGREE {
        for j in 0..NODES {
            let shifted = if j > 0 { 2.0 * t[k][j - 1] } else { 0.0 };
            t[k + 1][j] = shifted - t[k - 1][j];
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_smooth_functions_to_rounding() {
        let table = Uniform::build(0.0, 3.0, 20, |x| [x.exp(), (5.0 * x).sin()]);
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
        let table = Uniform::build(-1.0, 2.0, 1, |x| [p(x)]);
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

    #[test]
    fn octaves_resolve_a_logarithmic_singularity_at_zero() {
        let (lo, hi) = (0.017, 1.6);
        let table = Octaves::build(lo, hi, |x| [x.ln() * x.ln(), (x + 1.0).sqrt()]);
        for i in 0..=20_000 {
            let x = lo * (hi / lo).powf(i as f64 / 20_000.0);
            let [l, s] = table.eval(x);
            let want = x.ln() * x.ln();
            assert!(
                (l - want).abs() < 1e-14 * want.max(1.0),
                "ln^2 at {x}: {l} vs {want}"
            );
            assert!(
                (s / (x + 1.0).sqrt() - 1.0).abs() < 4e-15,
                "sqrt at {x}: {s}"
            );
        }
        // Octave boundaries and the ends are exact pieces' ends.
        for x in [0.0625, 0.125, 0.25, 0.5, 1.0, 0.75, lo, hi] {
            assert!(
                (table.eval(x)[1] / (x + 1.0).sqrt() - 1.0).abs() < 4e-15,
                "{x}"
            );
        }
    }

    #[test]
    fn octaves_never_index_out_of_bounds() {
        let table = Octaves::build(0.1, 1.0, |x| [x]);
        for x in [0.0, -1.0, 1e-300, 5e-324, 1e300, f64::INFINITY, f64::NAN] {
            let _ = table.eval(x);
        }
    }
}
