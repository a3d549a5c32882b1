//! The standard normal CDF and density, tabulated for the fit's inner loop.

/// The normal CDF and density tabulated on [-CDF_RANGE, CDF_RANGE] every 1/CDF_STEPS:
/// the inner loop's exponentials were half the cost of a frame.
const CDF_RANGE: f64 = 8.0;
const CDF_STEPS: f64 = 16.0;
const CDF_NODES: usize = (2.0 * CDF_RANGE * CDF_STEPS) as usize + 2;
static CDF_TABLE: std::sync::OnceLock<CdfTable> = std::sync::OnceLock::new();

/// The tabulated values and slopes, [`cdf_table`]'s.
pub(super) struct CdfTable([[f64; 2]; CDF_NODES]);

/// The table, computed on first use (fetch it once per loop, not per value).
pub(super) fn cdf_table() -> &'static CdfTable {
    CDF_TABLE.get_or_init(|| {
        let mut t = [[0.0; 2]; CDF_NODES];
        for (k, node) in t.iter_mut().enumerate() {
            let z = -CDF_RANGE + k as f64 / CDF_STEPS;
            *node = [normal_cdf(z), normal_pdf(z)];
        }
        CdfTable(t)
    })
}

/// Standard normal CDF (cubic Hermite between the tabulated values and slopes, error
/// below 1e-7) and density (linear, error below 2e-4), outside the table 0/1 and 0.
/// One value at a time: the reference [`cdf_pdf_lanes`] is checked against.
#[cfg(test)]
fn cdf_pdf(z: f64) -> (f64, f64) {
    let pos = (z + CDF_RANGE) * CDF_STEPS;
    if pos <= 0.0 {
        return (0.0, 0.0);
    }
    let k = pos as usize;
    if k + 1 >= CDF_NODES {
        return (1.0, 0.0);
    }
    let table = &cdf_table().0;
    let (a, b) = (table[k], table[k + 1]);
    let t = pos - k as f64;
    let h = 1.0 / CDF_STEPS;
    let (t2, t3) = (t * t, t * t * t);
    let cdf = (2.0 * t3 - 3.0 * t2 + 1.0) * a[0]
        + (t3 - 2.0 * t2 + t) * h * a[1]
        + (-2.0 * t3 + 3.0 * t2) * b[0]
        + (t3 - t2) * h * b[1];
    (cdf, a[1] + t * (b[1] - a[1]))
}

/// The normal CDF and density (see `cdf_pdf`) of four values at once, the same to the
/// bit: the table look-ups go one by one, the interpolation in vector arithmetic.
#[inline(always)]
pub(super) fn cdf_pdf_lanes(table: &CdfTable, z: &[f64; 4]) -> ([f64; 4], [f64; 4]) {
    use std::array::from_fn;
    let table = &table.0;
    // One simple loop per quantity, so that each becomes vector arithmetic (only the
    // look-ups go lane by lane).
    let pos: [f64; 4] = from_fn(|l| (z[l] + CDF_RANGE) * CDF_STEPS);
    // The node below each value, clamped to the table (out of its range the node does
    // not matter: the value is replaced below), is truncated in range, and the same
    // as clamping after the truncation.
    let k = pos.map(|p| p.max(0.0).min((CDF_NODES - 2) as f64) as i32 as usize);
    let a: [[f64; 2]; 4] = from_fn(|l| table[k[l]]);
    let b: [[f64; 2]; 4] = from_fn(|l| table[k[l] + 1]);
    let t: [f64; 4] = from_fn(|l| pos[l] - k[l] as f64);
    let h = 1.0 / CDF_STEPS;
    let cdf: [f64; 4] = from_fn(|l| {
        let (a, b, t) = (a[l], b[l], t[l]);
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * a[0]
            + (t3 - 2.0 * t2 + t) * h * a[1]
            + (-2.0 * t3 + 3.0 * t2) * b[0]
            + (t3 - t2) * h * b[1]
    });
    let pdf: [f64; 4] = from_fn(|l| a[l][1] + t[l] * (b[l][1] - a[l][1]));
    // Below the table 0 and 0, above it 1 and 0: chosen with bit masks, since a
    // choice between values became a branch per lane around the interpolation.
    let mask = |on: bool| (on as u64).wrapping_neg();
    let below: [bool; 4] = from_fn(|l| pos[l] <= 0.0);
    let above: [bool; 4] = from_fn(|l| !below[l] && pos[l] >= (CDF_NODES - 1) as f64);
    let inside: [u64; 4] = from_fn(|l| mask(!below[l] && !above[l]));
    let cdf = from_fn(|l| {
        f64::from_bits((cdf[l].to_bits() & inside[l]) | (1f64.to_bits() & mask(above[l])))
    });
    let pdf = from_fn(|l| f64::from_bits(pdf[l].to_bits() & inside[l]));
    (cdf, pdf)
}

/// Standard normal density.
pub(super) fn normal_pdf(z: f64) -> f64 {
    0.398_942_280_401_432_7 * (-0.5 * z * z).exp()
}

/// Standard normal CDF via erf (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
pub fn normal_cdf(z: f64) -> f64 {
    let x = z * std::f64::consts::FRAC_1_SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-x * x).exp();
    0.5 * (1.0 + erf.copysign(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tabulated_cdf_matches_the_direct_one() {
        for i in -1000..=1000 {
            let z = i as f64 * 0.0093;
            let (c, p) = cdf_pdf(z);
            assert!((c - normal_cdf(z)).abs() < 3e-7, "{z}");
            assert!((p - normal_pdf(z)).abs() < 2e-4, "{z}");
        }
    }

    #[test]
    fn four_at_a_time_is_the_same_to_the_bit() {
        for i in -2000..=2000 {
            let z = [0.0, 0.37, -0.011, 5.5].map(|o| i as f64 * 0.0047 + o);
            let (c, p) = cdf_pdf_lanes(cdf_table(), &z);
            for l in 0..4 {
                let (c1, p1) = cdf_pdf(z[l]);
                assert_eq!(
                    (c[l].to_bits(), p[l].to_bits()),
                    (c1.to_bits(), p1.to_bits())
                );
            }
        }
    }

    #[test]
    fn cdf_matches_known_values() {
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_cdf(1.0) - 0.841_344_746).abs() < 2e-7);
        assert!((normal_cdf(-2.0) - 0.022_750_132).abs() < 2e-7);
    }
}
