//! Counters and latency percentiles of the running server.

use std::sync::Mutex;

/// Latency percentiles, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LatencySummary {
    /// Samples recorded since start.
    pub count: u64,
    /// Median over the recent window, us.
    pub p50_us: f64,
    /// 99th percentile over the recent window, us.
    pub p99_us: f64,
    /// Maximum over the recent window, us.
    pub max_us: f64,
}

/// Keeps the most recent [`LatencyRecorder::WINDOW`] samples in a ring; the
/// lock is held only to store one number.
#[derive(Debug)]
pub struct LatencyRecorder {
    inner: Mutex<Ring>,
}

#[derive(Debug)]
struct Ring {
    samples: Vec<f64>,
    next: usize,
    count: u64,
}

impl Default for LatencyRecorder {
    fn default() -> Self {
        Self {
            inner: Mutex::new(Ring {
                samples: Vec::with_capacity(Self::WINDOW),
                next: 0,
                count: 0,
            }),
        }
    }
}

impl LatencyRecorder {
    /// Samples kept for percentiles.
    pub const WINDOW: usize = 1 << 16;

    /// Records one duration, us.
    pub fn record(&self, us: f64) {
        let mut r = self.inner.lock().expect("latency lock");
        if r.samples.len() < Self::WINDOW {
            r.samples.push(us);
        } else {
            let i = r.next;
            r.samples[i] = us;
        }
        r.next = (r.next + 1) % Self::WINDOW;
        r.count += 1;
    }

    /// Percentiles over the window.
    pub fn summary(&self) -> LatencySummary {
        let (mut v, count) = {
            let r = self.inner.lock().expect("latency lock");
            (r.samples.clone(), r.count)
        };
        if v.is_empty() {
            return LatencySummary::default();
        }
        v.sort_by(f64::total_cmp);
        LatencySummary {
            count,
            p50_us: percentile(&v, 0.50),
            p99_us: percentile(&v, 0.99),
            max_us: *v.last().expect("non-empty"),
        }
    }
}

/// The `q` quantile of sorted values (nearest rank).
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// A snapshot of the server's counters.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StatsSummary {
    /// Seconds since start.
    pub uptime_s: f64,
    /// Latest frame number.
    pub frames: u64,
    /// Force samples answered.
    pub force_samples: u64,
    /// Poses rejected.
    pub rejected_poses: u64,
    /// Watchers connected.
    pub watchers: u32,
    /// Instruments claimed now.
    pub claimed: Vec<String>,
    /// Server-side force computation.
    pub force_compute: LatencySummary,
    /// Of that, the collision query of the sample's instrument
    /// (free-running force loops only).
    pub force_collision: LatencySummary,
    /// Deformation steps.
    pub deformation_step: LatencySummary,
    /// Deformation steps that failed.
    pub failed_steps: u64,
    /// Bytes the solver's caches held after the last step (the compliance
    /// columns of the nodes contact has reached): they grow as contact
    /// reaches new tissue, up to the cache's limit.
    pub solver_cache_bytes: u64,
    /// Recording entries dropped since the start (the recorder's queue to
    /// the disk was full, or its writing failed), all kinds together; 0 when
    /// the session is not recorded. See `recording::RecorderStats::lost`.
    pub recording_lost: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles() {
        let r = LatencyRecorder::default();
        for i in 1..=100 {
            r.record(i as f64);
        }
        let s = r.summary();
        assert_eq!(
            (s.count, s.p50_us, s.p99_us, s.max_us),
            (100, 50.0, 99.0, 100.0)
        );
        assert!(percentile(&[], 0.5).is_nan());
    }
}
