//! The pose budget of a free-running haptic stream: a token bucket over
//! wall-clock time.
//!
//! The bucket holds at most `C = r T_b` tokens (`r` the sustained rate,
//! poses/s, `T_b` = [`POSE_BURST_S`]) and refills at `r`: after `dt` s it
//! holds `min(C, n + r dt)`. A pose takes one token; with less than one left
//! it is over the rate. Over any window of `T` s a stream is thus served at
//! most `C + r T` poses, and a stream at or below `r` is never refused.

/// Sustained pose rate a haptic stream is served at in free-running mode, as
/// a multiple of the scene's `loops.haptic_rate_hz` (2 kHz for a 1 kHz scene).
/// Poses above it are answered at once with a `RESOURCE_EXHAUSTED` rejection
/// (nothing computed, nothing applied), so a flooding client cannot take more
/// than its share of the CPU from the other client and the deformation loop.
/// Stepped mode has no limit: its force loop waits for the deformation loop.
pub const MAX_POSE_RATE_FACTOR: f64 = 2.0;

/// Burst a haptic stream may send above the sustained rate, seconds of poses
/// at that rate (2000 poses at 2 kHz): a 1 kHz client whose poses queued up
/// during a stall of up to 2 s (network, scheduling) drains its backlog
/// without a rejection.
pub const POSE_BURST_S: f64 = 1.0;

/// A token bucket over wall-clock time: `rate` poses a second sustained,
/// `rate * POSE_BURST_S` at once.
#[derive(Debug)]
pub struct PoseBudget {
    /// Sustained rate, poses a second.
    pub rate_hz: f64,
    tokens: f64,
    capacity: f64,
    last: std::time::Instant,
}

impl PoseBudget {
    /// A full budget of `rate_hz` poses a second.
    pub fn new(rate_hz: f64) -> Self {
        let capacity = (rate_hz * POSE_BURST_S).max(1.0);
        Self {
            rate_hz,
            tokens: capacity,
            capacity,
            last: std::time::Instant::now(),
        }
    }

    /// Takes one pose from the budget; false when the stream is over its rate.
    pub fn take(&mut self) -> bool {
        self.take_at(std::time::Instant::now())
    }

    /// [`PoseBudget::take`] at `now`.
    pub fn take_at(&mut self, now: std::time::Instant) -> bool {
        let dt = now.duration_since(self.last).as_secs_f64();
        self.last = now;
        self.tokens = (self.tokens + dt * self.rate_hz).min(self.capacity);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{POSE_BURST_S, PoseBudget};
    use std::time::{Duration, Instant};

    /// A flood gets the burst, then the sustained rate; a stream at the rate
    /// is never refused; a stall refills at most the burst.
    #[test]
    fn pose_budget_allows_the_rate_and_the_burst_only() {
        let rate = 2000.0;
        let burst = (rate * POSE_BURST_S) as usize;
        let t0 = Instant::now();
        let mut b = PoseBudget::new(rate);
        b.last = t0;
        // 10 kHz for 2 s: burst + 2 s at 2 kHz served (within one pose).
        let served = (0..20_000)
            .filter(|&i| b.take_at(t0 + Duration::from_micros(100 * i)))
            .count();
        let expected = burst + 2 * rate as usize;
        assert!(served.abs_diff(expected) <= 1, "{served} vs {expected}");
        // At 1 kHz after a 10 s pause: every pose served.
        let t1 = t0 + Duration::from_secs(12);
        assert!((0..5_000).all(|i| b.take_at(t1 + Duration::from_millis(i))));
        // A 1.5 s stall at 1 kHz, then the 1500 queued poses at once: served.
        let t2 = t1 + Duration::from_millis(5_000 + 1_500);
        assert!((0..1_500).all(|_| b.take_at(t2)));
        // The budget is then empty: the next pose at the same instant is not.
        let mut empty = PoseBudget::new(rate);
        empty.last = t0;
        assert!((0..burst).all(|_| empty.take_at(t0)));
        assert!(!empty.take_at(t0));
    }
}
