//! A small deterministic random number generator of our own, so that a frame rendered
//! from a seed is bit-identical across crate versions and platforms: SplitMix64 to
//! expand seeds, xoshiro256** for the stream, and Gaussian noise from a fixed table of
//! normal quantiles (fast enough to fill a 640x480 frame in well under a millisecond).

use std::sync::OnceLock;

/// SplitMix64: turns any 64-bit seed (including 0) into well-mixed state words.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// Derives an independent seed for a named part of a frame (noise, particles, ...), so
/// that changing one part of a scene does not reshuffle the others.
pub fn sub_seed(seed: u64, stream: u64) -> u64 {
    let mut mix = SplitMix64::new(seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03));
    mix.next_u64()
}

/// xoshiro256** (Blackman and Vigna), seeded through SplitMix64.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        let mut mix = SplitMix64::new(seed);
        Rng {
            s: [
                mix.next_u64(),
                mix.next_u64(),
                mix.next_u64(),
                mix.next_u64(),
            ],
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        let result = self.s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = self.s[1] << 17;
        self.s[2] ^= self.s[0];
        self.s[3] ^= self.s[1];
        self.s[1] ^= self.s[2];
        self.s[0] ^= self.s[3];
        self.s[2] ^= t;
        self.s[3] = self.s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Log-uniform in [lo, hi) (both > 0): every scale equally likely.
    pub fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }

    /// Uniform integer in [lo, hi] (inclusive).
    pub fn int(&mut self, lo: u32, hi: u32) -> u32 {
        let span = u64::from(hi.saturating_sub(lo)) + 1;
        lo + (((self.next_u64() >> 32) * span) >> 32) as u32
    }

    /// True with probability p.
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// +1 or -1 with equal probability.
    pub fn sign(&mut self) -> f64 {
        if self.next_u64() >> 63 == 0 {
            1.0
        } else {
            -1.0
        }
    }

    /// One standard normal deviate (from the quantile table; tails cut at ~4.3 sigma).
    pub fn normal(&mut self) -> f64 {
        f64::from(normal_table()[(self.next_u64() >> 48) as usize])
    }
}

const TABLE_BITS: u32 = 16;

/// 2^16 standard normal quantiles at probabilities (i + 1/2) / 2^16: indexing it with
/// uniform 16-bit numbers gives Gaussian deviates (variance 0.9997, tails at 4.3 sigma).
pub fn normal_table() -> &'static [f32] {
    static TABLE: OnceLock<Vec<f32>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let n = 1usize << TABLE_BITS;
        (0..n)
            .map(|i| inverse_normal_cdf((i as f64 + 0.5) / n as f64) as f32)
            .collect()
    })
}

/// Adds `sigma` times Gaussian noise to every sample, four deviates per 64-bit draw.
pub fn add_gaussian_noise(samples: &mut [f32], sigma: f32, rng: &mut Rng) {
    if sigma == 0.0 {
        return;
    }
    let table = normal_table();
    let mut chunks = samples.chunks_exact_mut(4);
    for chunk in &mut chunks {
        let bits = rng.next_u64();
        for (k, v) in chunk.iter_mut().enumerate() {
            *v += sigma * table[((bits >> (16 * k)) & 0xFFFF) as usize];
        }
    }
    let bits = rng.next_u64();
    for (k, v) in chunks.into_remainder().iter_mut().enumerate() {
        *v += sigma * table[((bits >> (16 * k)) & 0xFFFF) as usize];
    }
}

/// Acklam's rational approximation of the standard normal quantile (relative error
/// below 1.2e-9), enough for a noise table.
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xoshiro_matches_reference_stream() {
        // xoshiro256** from state [1, 2, 3, 4] (reference implementation's output).
        let mut rng = Rng { s: [1, 2, 3, 4] };
        let got: Vec<u64> = (0..3).map(|_| rng.next_u64()).collect();
        assert_eq!(got, vec![11520, 0, 1509978240]);
    }

    #[test]
    fn splitmix_matches_reference_stream() {
        let mut mix = SplitMix64::new(1234567);
        assert_eq!(mix.next_u64(), 6457827717110365317);
        assert_eq!(mix.next_u64(), 3203168211198807973);
    }

    #[test]
    fn normal_table_has_unit_variance_and_zero_mean() {
        let t = normal_table();
        let n = t.len() as f64;
        let mean = t.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = t.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>() / n;
        assert!(mean.abs() < 1e-6, "mean {mean}");
        assert!((var - 1.0).abs() < 1e-3, "variance {var}");
        // The median quantile pair straddles zero symmetrically.
        assert_eq!(t[t.len() / 2], -t[t.len() / 2 - 1]);
    }

    #[test]
    fn noise_has_the_requested_sigma() {
        let mut rng = Rng::new(7);
        let mut v = vec![0.0f32; 200_003];
        add_gaussian_noise(&mut v, 22.0, &mut rng);
        let n = v.len() as f64;
        let mean = v.iter().map(|&x| f64::from(x)).sum::<f64>() / n;
        let sd = (v
            .iter()
            .map(|&x| (f64::from(x) - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!(mean.abs() < 0.2, "mean {mean}");
        assert!((sd - 22.0).abs() < 0.15, "sd {sd}");
        assert!(v[v.len() - 1] != 0.0, "the remainder is noised too");
    }

    #[test]
    fn uniform_helpers_stay_in_range() {
        let mut rng = Rng::new(3);
        for _ in 0..10_000 {
            let u = rng.uniform(-2.0, 5.0);
            assert!((-2.0..5.0).contains(&u));
            let k = rng.int(3, 7);
            assert!((3..=7).contains(&k));
            let l = rng.log_uniform(1.0, 100.0);
            assert!((1.0..100.0).contains(&l));
        }
    }
}
