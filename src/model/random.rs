//! Seeded randomness: ChaCha8 seeded from a `u64`, so a seed names the same numbers on every
//! machine and with every thread count.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The project's seeded generator.
#[must_use]
pub fn seeded_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A uniformly distributed unit quaternion `[w, x, y, z]` (Shoemake's method).
pub fn random_rotation(rng: &mut ChaCha8Rng) -> [f64; 4] {
    let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
    let tau = std::f64::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    [
        b * (tau * u3).cos(),
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
    ]
}

/// A value whose logarithm is uniform in `[ln lo, ln hi)`.
pub fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}
