//! Jacobi elliptic functions sn, cn, dn by the arithmetic-geometric mean (Abramowitz &
//! Stegun 16.4). The elastica's arclength is an incomplete elliptic integral of the first
//! kind in the beam angle, so the shape at a given arclength is a Jacobi amplitude; see
//! [`super::elastica::centreline`].

/// The AGM converges quadratically; k' >= sin(0.5 deg) in the model's range needs ~5.
const MAX_STEPS: usize = 16;

/// sn(u, k), cn(u, k), dn(u, k) for modulus `k` in [0, 1) with complementary modulus
/// `k_prime` = sqrt(1 - k^2) given separately (so that k near 1 loses nothing).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Jacobi {
    pub sn: f64,
    pub cn: f64,
    pub dn: f64,
}

/// sn, cn and dn of `u` for modulus `k` and complementary modulus `k_prime`.
pub(crate) fn jacobi(u: f64, k: f64, k_prime: f64) -> Jacobi {
    let mut a = [0.0; MAX_STEPS + 1];
    let mut c = [0.0; MAX_STEPS + 1];
    let (mut an, mut bn) = (1.0, k_prime);
    c[0] = k;
    a[0] = an;
    let mut steps = 0;
    while steps < MAX_STEPS && c[steps].abs() > f64::EPSILON * an {
        let next = (an + bn) / 2.0;
        c[steps + 1] = (an - bn) / 2.0;
        bn = (an * bn).sqrt();
        an = next;
        steps += 1;
        a[steps] = an;
    }
    let mut phi = (1u64 << steps) as f64 * an * u;
    for n in (1..=steps).rev() {
        phi = (phi + (c[n] / a[n] * phi.sin()).asin()) / 2.0;
    }
    let (sn, cn) = phi.sin_cos();
    // dn^2 = 1 - k^2 sn^2 = k'^2 + k^2 cn^2: two positive terms, no cancellation.
    let dn = (k_prime * k_prime + k * k * cn * cn).sqrt();
    Jacobi { sn, cn, dn }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::carlson::rf;

    /// Incomplete elliptic integral of the first kind, F(phi, k), for |phi| <= pi/2.
    fn legendre_f(phi: f64, k: f64) -> f64 {
        let (s, c) = phi.sin_cos();
        s * rf(c * c, 1.0 - k * k * s * s, 1.0)
    }

    #[test]
    fn inverts_the_elliptic_integral_of_the_first_kind() {
        for k in [0.0, 0.3, 0.707, 0.95, 0.999_96] {
            let k_prime = (1.0f64 - k * k).sqrt();
            for i in 0..=40 {
                let phi = 1.55 * i as f64 / 40.0;
                let j = jacobi(legendre_f(phi, k), k, k_prime);
                assert!((j.sn - phi.sin()).abs() < 4e-15, "k {k} phi {phi}: {j:?}");
                assert!((j.cn - phi.cos()).abs() < 4e-15, "k {k} phi {phi}: {j:?}");
                let dn = (1.0 - k * k * phi.sin().powi(2)).sqrt();
                assert!((j.dn - dn).abs() < 4e-15, "k {k} phi {phi}: {j:?}");
            }
        }
    }

    #[test]
    fn reduces_to_circular_functions_at_zero_modulus() {
        for u in [0.0, 0.1, 1.0, 2.5] {
            let j = jacobi(u, 0.0, 1.0);
            assert_eq!((j.sn, j.cn, j.dn), (u.sin(), u.cos(), 1.0));
        }
    }
}
