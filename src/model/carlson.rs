//! Carlson's symmetric elliptic integrals R_F and R_D by the duplication theorem
//! (Carlson 1995; series of DLMF 19.36.1 and 19.36.2 to degree 7), the building blocks of
//! the exact elastica in [`super::elastica`].
//!
//! [`rf_minus_one`] returns R_F - 1 without cancellation when the arguments are close to
//! 1: the elastica's projected shortening is (R_F - 1) / R_F with arguments within
//! sin(phi0) of 1, so at 0.01 deg it is ~1e-8 and subtracting 1 from a computed R_F would
//! leave only 8 correct digits. The iteration carries the arguments' mean offset from 1
//! and their deviations from the mean separately, and every update is a sum of terms of
//! one sign.

/// Largest scaled deviation at which the R_F series is cut off. The first term left out
/// is of degree 8 in the deviation, and R_F - 1 is of degree 2, so the relative error of
/// R_F - 1 is about `RF_TOL^6` = 6e-17.
const RF_TOL: f64 = 0.002;
/// Same for R_D, whose value is not near zero: `RD_TOL^8` = 1e-16.
const RD_TOL: f64 = 0.01;
/// Each duplication shrinks the deviations fourfold; 40 steps cover any finite input.
const MAX_STEPS: usize = 40;

/// R_F(x, y, z) - 1 for x, y, z >= 0 (at most one zero), given the arguments `x` and
/// their offsets from one `d` (d_i = 1 - x_i, supplied by the caller without rounding
/// loss, e.g. sin(phi) rather than 1 - (1 - sin(phi))).
pub(crate) fn rf_minus_one(x: [f64; 3], d: [f64; 3]) -> f64 {
    let mut x = x;
    let mut mean_d = (d[0] + d[1] + d[2]) / 3.0;
    let mut dev = [d[0] - mean_d, d[1] - mean_d, d[2] - mean_d];
    let mut mean = 1.0 - mean_d;
    let mut scaled = dev.map(|e| e / mean);
    for _ in 0..MAX_STEPS {
        if scaled.iter().all(|s| s.abs() < RF_TOL) {
            break;
        }
        let root = x.map(f64::sqrt);
        // 3 - lambda = 3 mean_d + mean * sum(1 - r_k), with r_k = sqrt(x_i x_j) / mean and
        // (k, i, j) a rotation of (0, 1, 2). The sum is rewritten so that its O(deviation)
        // parts, which cancel exactly because the deviations sum to zero, never appear.
        let mut lambda = 0.0;
        let mut sum = 0.0;
        for (k, i, j) in [(0, 1, 2), (1, 2, 0), (2, 0, 1)] {
            let product = root[i] * root[j];
            lambda += product;
            let r = product / mean;
            let (sk, cross) = (scaled[k], scaled[i] * scaled[j]);
            sum += sk * (sk + cross) / (2.0 * (1.0 + r) * (1.0 + r)) - cross / (1.0 + r);
        }
        mean_d += mean * sum / 4.0;
        mean = 1.0 - mean_d;
        dev = dev.map(|e| e / 4.0);
        scaled = dev.map(|e| e / mean);
        x = x.map(|v| (v + lambda) / 4.0);
    }
    let series = rf_series_minus_one(scaled[0], scaled[1]);
    let root_mean = mean.sqrt();
    let inv_root_minus_one = mean_d / (root_mean * (1.0 + root_mean));
    inv_root_minus_one * (1.0 + series) + series
}

/// R_F(x, y, z) for x, y, z >= 0, at most one of them zero, by the plain duplication
/// (tests only: the model needs R_F - 1).
#[cfg(test)]
pub(crate) fn rf(x: f64, y: f64, z: f64) -> f64 {
    let mut v = [x, y, z];
    let mut mean = (x + y + z) / 3.0;
    for _ in 0..MAX_STEPS {
        if v.iter().all(|a| (mean - a).abs() < RF_TOL * mean) {
            break;
        }
        let r = v.map(f64::sqrt);
        let lambda = r[0] * r[1] + r[1] * r[2] + r[2] * r[0];
        v = v.map(|a| (a + lambda) / 4.0);
        mean = (mean + lambda) / 4.0;
    }
    (1.0 + rf_series_minus_one((mean - v[0]) / mean, (mean - v[1]) / mean)) / mean.sqrt()
}

/// The R_F series 1 - E2/10 + E3/14 + ... (DLMF 19.36.1) minus its leading 1, in the
/// scaled deviations X = 1 - x/A, Y = 1 - y/A (Z = -X - Y).
fn rf_series_minus_one(dx: f64, dy: f64) -> f64 {
    let dz = -(dx + dy);
    let e2 = dx * dy - dz * dz;
    let e3 = dx * dy * dz;
    -e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0 - 5.0 * e2 * e2 * e2 / 208.0
        + 3.0 * e3 * e3 / 104.0
        + e2 * e2 * e3 / 16.0
}

/// R_D(x, y, z) = (3/2) integral_0^inf dt / ((t+z) sqrt((t+x)(t+y)(t+z))), for x, y >= 0
/// (at most one zero) and z > 0.
pub(crate) fn rd(x: f64, y: f64, z: f64) -> f64 {
    let (mut x, mut y, mut z) = (x, y, z);
    let mut tail = 0.0;
    let mut scale = 1.0;
    let mut mean = (x + y + 3.0 * z) / 5.0;
    for _ in 0..MAX_STEPS {
        let deviation = (mean - x).abs().max((mean - y).abs()).max((mean - z).abs());
        if deviation < RD_TOL * mean {
            break;
        }
        let (rx, ry, rz) = (x.sqrt(), y.sqrt(), z.sqrt());
        let lambda = rx * ry + ry * rz + rz * rx;
        tail += scale / (rz * (z + lambda));
        scale /= 4.0;
        x = (x + lambda) / 4.0;
        y = (y + lambda) / 4.0;
        z = (z + lambda) / 4.0;
        mean = (mean + lambda) / 4.0;
    }
    let dx = (mean - x) / mean;
    let dy = (mean - y) / mean;
    3.0 * tail + scale * rd_series(dx, dy) / (mean * mean.sqrt())
}

/// The R_D series of DLMF 19.36.2 to degree 7 in the scaled deviations
/// X = 1 - x/A, Y = 1 - y/A (Z = -(X + Y)/3), A = (x + y + 3z)/5.
fn rd_series(dx: f64, dy: f64) -> f64 {
    let dz = -(dx + dy) / 3.0;
    let (xy, zz) = (dx * dy, dz * dz);
    let e2 = xy - 6.0 * zz;
    let e3 = (3.0 * xy - 8.0 * zz) * dz;
    let e4 = 3.0 * (xy - zz) * zz;
    let e5 = xy * zz * dz;
    1.0 - 3.0 * e2 / 14.0 + e3 / 6.0 + 9.0 * e2 * e2 / 88.0 - 3.0 * e4 / 22.0 - 9.0 * e2 * e3 / 52.0
        + 3.0 * e5 / 26.0
        - e2 * e2 * e2 / 16.0
        + 3.0 * e3 * e3 / 40.0
        + 3.0 * e2 * e4 / 20.0
        + 45.0 * e2 * e2 * e3 / 272.0
        - 9.0 * (e3 * e4 + e2 * e5) / 68.0
}

#[cfg(test)]
// The reference values keep the digits mpmath printed.
#[allow(clippy::excessive_precision)]
mod tests {
    use super::*;

    fn assert_rel(got: f64, want: f64, tol: f64) {
        let err = (got / want - 1.0).abs();
        assert!(
            err <= tol,
            "got {got:e}, want {want:e}: relative error {err:e}"
        );
    }

    /// Values from mpmath 1.3 `elliprf` / `elliprd` at 40 digits (Carlson 1995 checks
    /// plus arguments spanning 10 decades).
    #[test]
    fn rf_matches_reference_values() {
        let cases = [
            (
                [1.0, 2.0, 0.0],
                1.311_028_777_146_059_905_232_419_794_945_56,
            ),
            (
                [2.0, 3.0, 4.0],
                0.584_082_841_677_151_706_692_849_168_925_668,
            ),
            (
                [0.5, 1.0, 1.0],
                1.110_720_734_539_591_561_753_970_247_515_17,
            ),
            (
                [1e-5, 1e-5, 1e5],
                0.038_598_990_847_203_310_200_025_045_924_159_1,
            ),
            ([1.0, 1.0, 1.0], 1.0),
        ];
        for (args, want) in cases {
            assert_rel(rf(args[0], args[1], args[2]), want, 4e-16);
        }
    }

    #[test]
    fn rd_matches_reference_values() {
        let cases = [
            (
                [0.0, 2.0, 1.0],
                1.797_210_352_103_388_311_159_883_738_420_49,
            ),
            (
                [2.0, 3.0, 4.0],
                0.165_105_272_942_610_533_486_713_418_873_083,
            ),
            (
                [1e-5, 1e5, 1e-3],
                8.624_393_187_358_519_615_733_017_871_516_39,
            ),
            ([1.0, 1.0, 1.0], 1.0),
        ];
        for (args, want) in cases {
            assert_rel(rd(args[0], args[1], args[2]), want, 4e-16);
        }
    }

    /// R_F(1 - s, 1 + s, 1 - s^2) - 1 is 4 s^2/15 + O(s^4): at s = 1e-6 a plain R_F minus
    /// one would keep 4 digits; mpmath at 60 digits gives the reference values.
    #[test]
    fn rf_minus_one_keeps_relative_precision_near_one() {
        let cases = [
            (1e-6, 2.666_666_666_668_190_476_190_477_256_077_256e-13),
            (1e-3, 2.666_668_190_477_256_078_075_128_151_986_173e-7),
            (0.3, 0.025_317_766_814_291_731_839_417_984_957_489_1),
        ];
        for (s, want) in cases {
            let got = rf_minus_one([1.0 - s, 1.0 + s, 1.0 - s * s], [s, -s, s * s]);
            assert_rel(got, want, 2e-15);
        }
    }
}
