//! Slow, obviously-right references for the tests (test builds only): the corrected
//! Eqs. 9 and 10 of the paper by adaptive Gauss-Kronrod quadrature, and the beam's
//! differential equation by Runge-Kutta. Neither uses an elliptic integral, so they check
//! the closed form independently.

/// Gauss-Kronrod 7-15 (QUADPACK's qk15): Kronrod nodes on [0, 1) and their weights; the
/// odd-indexed nodes and the centre are the 7-point Gauss nodes, with weights `GAUSS`.
const KRONROD_NODES: [f64; 8] = [
    0.991_455_371_120_812_6,
    0.949_107_912_342_758_5,
    0.864_864_423_359_769_1,
    0.741_531_185_599_394_4,
    0.586_087_235_467_691_1,
    0.405_845_151_377_397_2,
    0.207_784_955_007_898_5,
    0.0,
];
const KRONROD_WEIGHTS: [f64; 8] = [
    0.022_935_322_010_529_225,
    0.063_092_092_629_978_55,
    0.104_790_010_322_250_18,
    0.140_653_259_715_525_92,
    0.169_004_726_639_267_9,
    0.190_350_578_064_785_4,
    0.204_432_940_075_298_9,
    0.209_482_141_084_727_83,
];
const GAUSS_WEIGHTS: [f64; 4] = [
    0.129_484_966_168_869_7,
    0.279_705_391_489_276_7,
    0.381_830_050_505_118_9,
    0.417_959_183_673_469_4,
];

/// Kronrod and Gauss estimates of the integrals of `F` functions over [a, b].
fn gauss_kronrod<const F: usize>(
    f: &impl Fn(f64) -> [f64; F],
    a: f64,
    b: f64,
) -> ([f64; F], [f64; F]) {
    let (centre, half) = ((a + b) / 2.0, (b - a) / 2.0);
    let (mut kronrod, mut gauss) = ([0.0; F], [0.0; F]);
    for (i, (&x, &w)) in KRONROD_NODES.iter().zip(&KRONROD_WEIGHTS).enumerate() {
        let values: Vec<[f64; F]> = if x == 0.0 {
            vec![f(centre)]
        } else {
            vec![f(centre - half * x), f(centre + half * x)]
        };
        for v in &values {
            for m in 0..F {
                kronrod[m] += w * v[m] * half;
                if i % 2 == 1 {
                    gauss[m] += GAUSS_WEIGHTS[i / 2] * v[m] * half;
                }
            }
        }
    }
    (kronrod, gauss)
}

/// Integrals over [a, b] of `F` positive functions, each to relative accuracy `rel_tol`
/// (an interval is split until its Kronrod-Gauss difference is below `rel_tol` times its
/// own integral, for every function; positivity makes that a global bound).
pub(crate) fn integrate<const F: usize>(
    f: impl Fn(f64) -> [f64; F],
    a: f64,
    b: f64,
    rel_tol: f64,
) -> [f64; F] {
    let mut total = [0.0; F];
    let mut stack = vec![(a, b, 0)];
    while let Some((lo, hi, depth)) = stack.pop() {
        let (kronrod, gauss) = gauss_kronrod(&f, lo, hi);
        let converged = (0..F).all(|m| (kronrod[m] - gauss[m]).abs() <= rel_tol * kronrod[m].abs());
        if converged || depth >= 40 {
            for m in 0..F {
                total[m] += kronrod[m];
            }
        } else {
            let mid = (lo + hi) / 2.0;
            stack.push((lo, mid, depth + 1));
            stack.push((mid, hi, depth + 1));
        }
    }
    total
}

/// sin(x)/x, 1 at 0.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

/// [alpha, delta/L, Delta/L] for 0 < phi0 < pi/2 from the corrected Eqs. 9 and 10 and the
/// shortening integral, each an integral over phi in [0, phi0] of a function over
/// sqrt(sin phi0 - sin phi). The substitution phi = phi0 (1 - t^2) and
/// sin phi0 - sin phi = phi0 t^2 cos(phi0 (1 - t^2/2)) sinc(phi0 t^2/2) make the
/// integrands smooth on [0, 1]: dphi / sqrt(sin phi0 - sin phi) = 2 sqrt(phi0) h(t) dt.
pub(crate) fn elastica_by_quadrature(phi0: f64) -> [f64; 3] {
    let integrands = |t: f64| {
        let phi = phi0 * (1.0 - t * t);
        let h = 1.0 / ((phi0 * (1.0 - t * t / 2.0)).cos() * sinc(phi0 * t * t / 2.0)).sqrt();
        let half_sin = (phi / 2.0).sin();
        [h, phi.sin() * h, 2.0 * half_sin * half_sin * h]
    };
    let [i_alpha, i_delta, i_shortening] = integrate(integrands, 0.0, 1.0, 1e-15);
    let sqrt_alpha = (2.0 * phi0).sqrt() * i_alpha;
    // (1/sqrt(2 alpha)) * 2 sqrt(phi0) = sqrt(2 phi0) / sqrt(alpha).
    let factor = (2.0 * phi0).sqrt() / sqrt_alpha;
    [
        sqrt_alpha * sqrt_alpha,
        factor * i_delta,
        factor * i_shortening,
    ]
}

/// [phi, x/L, y/L] along the beam at s/L = 0, 1/steps, ..., 1 from the beam equation
/// phi'' = -alpha cos(phi) (Eq. 4 over L), phi(0) = 0, phi'(0) = sqrt(2 alpha sin phi0)
/// (Eq. 8), x' = cos(phi), y' = sin(phi), by classical Runge-Kutta.
pub(crate) fn centreline_by_ode(alpha: f64, phi0: f64, steps: usize) -> Vec<[f64; 3]> {
    let derivative = |u: [f64; 4]| [u[1], -alpha * u[0].cos(), u[0].cos(), u[0].sin()];
    let h = 1.0 / steps as f64;
    let mut u = [0.0, (2.0 * alpha * phi0.sin()).sqrt(), 0.0, 0.0];
    let mut path = vec![[u[0], u[2], u[3]]];
    let add = |u: [f64; 4], k: [f64; 4], c: f64| std::array::from_fn(|m| u[m] + c * k[m]);
    for _ in 0..steps {
        let k1 = derivative(u);
        let k2 = derivative(add(u, k1, h / 2.0));
        let k3 = derivative(add(u, k2, h / 2.0));
        let k4 = derivative(add(u, k3, h));
        u = std::array::from_fn(|m| u[m] + h / 6.0 * (k1[m] + 2.0 * k2[m] + 2.0 * k3[m] + k4[m]));
        path.push([u[0], u[2], u[3]]);
    }
    path
}

/// A small deterministic generator (SplitMix64) for reproducible random test points.
pub(crate) struct SplitMix(pub u64);

impl SplitMix {
    /// Uniform in [0, 1).
    pub(crate) fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadrature_integrates_known_integrals() {
        let [a, b] = integrate(|x| [x.exp(), 1.0 / (1.0 + x * x)], 0.0, 1.0, 1e-15);
        assert!((a / (1f64.exp() - 1.0) - 1.0).abs() < 1e-15, "{a}");
        assert!((b / std::f64::consts::FRAC_PI_4 - 1.0).abs() < 1e-15, "{b}");
        // A near-singular integrand like the elastica's near 90 deg.
        let eps = 1e-4;
        let [c] = integrate(|x| [1.0 / (eps + x * x).sqrt()], 0.0, 1.0, 1e-15);
        let want = ((1.0 + (1.0 + eps).sqrt()) / eps.sqrt()).ln();
        assert!((c / want - 1.0).abs() < 1e-14, "{c} vs {want}");
    }

    #[test]
    fn runge_kutta_matches_linear_beam_theory_at_small_load() {
        // Small load: phi' = alpha (1 - s), so phi(1) = alpha/2 and y(1) = alpha/3, with
        // relative corrections O(alpha^2).
        let alpha = 1e-6;
        let path = centreline_by_ode(alpha, alpha / 2.0, 100);
        let [phi, x, y] = path[100];
        assert!((phi / (alpha / 2.0) - 1.0).abs() < 1e-10, "{phi}");
        assert!((y / (alpha / 3.0) - 1.0).abs() < 1e-10, "{y}");
        assert!((x - 1.0).abs() < 1e-12, "{x}");
    }
}
