//! Reproducible numbers for the engine's unit tests: a 64-bit linear
//! congruential generator (Knuth's MMIX constants), nothing to install, the
//! same sequence on every machine.

/// Numbers uniform in `[0, 1)` from `seed` (53 bits of each state).
pub(crate) fn unit(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    }
}
