//! Watches the deformation loop's pace and warns, once, when its steps take
//! longer than the scene's interval (`loops.deformation_interval_s`).
//!
//! A step slower than the interval means, in stepped mode, that a replay runs
//! slower than real time, by at least the ratio of the two (the steps alone;
//! collision and the force samples add to it); free-running, that frames
//! come less often than the scene asks and the force loops extrapolate from
//! older models. Neither is an error, but a user should hear of it rather
//! than find out from the timings. The monitor samples the published
//! snapshot a few times a second (a lock read, no work in the loop itself)
//! and warns when [`BEHIND_FRAMES`] distinct frames in a row took longer
//! than the interval; a single slow step (a page fault, a busy machine) does
//! not count.

use fissure_engine::sim::Simulation;
use std::sync::Arc;
use std::time::Duration;

/// Distinct frames in a row, each slower than the interval, before the
/// warning.
pub const BEHIND_FRAMES: usize = 3;

/// How often the snapshot is sampled.
pub const SAMPLE_INTERVAL: Duration = Duration::from_millis(200);

/// The loop is behind: the step times seen, against the interval.
#[derive(Debug, Clone, PartialEq)]
pub struct Behind {
    /// The slow frames seen, in the order seen.
    pub frames: Vec<u64>,
    /// Median wall-clock time of their steps, s.
    pub median_step_s: f64,
    /// The scene's interval, s.
    pub interval_s: f64,
}

impl Behind {
    /// How many times slower than the interval the steps are.
    pub fn ratio(&self) -> f64 {
        self.median_step_s / self.interval_s
    }
}

/// The state of the check over the frames sampled.
#[derive(Debug, Clone)]
pub struct PaceCheck {
    interval_s: f64,
    last_frame: Option<u64>,
    slow: Vec<(u64, f64)>,
    warned: bool,
}

impl PaceCheck {
    /// A check against `interval_s` (s).
    pub fn new(interval_s: f64) -> Self {
        Self {
            interval_s,
            last_frame: None,
            slow: Vec::with_capacity(BEHIND_FRAMES),
            warned: false,
        }
    }

    /// Looks at one sample: the latest frame's number and the wall-clock
    /// time of its step, s (0 for a frame no step produced: the rest state,
    /// a reset). Returns the finding once, the first time [`BEHIND_FRAMES`]
    /// distinct frames in a row were slower than the interval.
    pub fn observe(&mut self, frame: u64, step_s: f64) -> Option<Behind> {
        if self.warned || self.last_frame == Some(frame) {
            return None;
        }
        self.last_frame = Some(frame);
        // A NaN step time counts as within the interval.
        if step_s.partial_cmp(&self.interval_s) != Some(std::cmp::Ordering::Greater) {
            self.slow.clear();
            return None;
        }
        self.slow.push((frame, step_s));
        if self.slow.len() < BEHIND_FRAMES {
            return None;
        }
        self.warned = true;
        let mut times: Vec<f64> = self.slow.iter().map(|s| s.1).collect();
        times.sort_by(f64::total_cmp);
        Some(Behind {
            frames: self.slow.iter().map(|s| s.0).collect(),
            median_step_s: times[times.len() / 2],
            interval_s: self.interval_s,
        })
    }
}

/// Samples `sim`'s snapshot until `stopping` turns true or the warning has
/// been given (at most once).
pub async fn watch_pace(sim: Arc<Simulation>, mut stopping: tokio::sync::watch::Receiver<bool>) {
    let interval_s = sim.scene().loops.deformation_interval_s;
    let stepped = sim.is_stepped();
    let mut check = PaceCheck::new(interval_s);
    let mut tick = tokio::time::interval(SAMPLE_INTERVAL);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stopping.wait_for(|s| *s) => return,
        }
        let snap = sim.snapshot();
        let step_s = snap.frame_summary.timings.total_us * 1e-6;
        if let Some(b) = check.observe(snap.frame, step_s) {
            let effect = if stepped {
                format!(
                    "stepped replays run at least {:.1}x slower than real time (the steps alone)",
                    b.ratio()
                )
            } else {
                "frames come less often than the scene asks, and the force loops use older models"
                    .to_owned()
            };
            tracing::warn!(
                scene = %sim.scene().name,
                frames = ?b.frames,
                step_ms = b.median_step_s * 1e3,
                interval_ms = b.interval_s * 1e3,
                "the deformation loop is behind its interval: steps take {:.1} ms against \
                 loops.deformation_interval_s = {:.1} ms; {effect} (a smaller model, a faster \
                 solver strategy or a longer interval would keep up)",
                b.median_step_s * 1e3,
                b.interval_s * 1e3,
            );
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three distinct frames slower than the interval give one finding with
    /// their median; a fast frame in between restarts the count; the same
    /// frame sampled twice counts once; nothing after the first finding.
    #[test]
    fn warns_once_after_three_slow_frames_in_a_row() {
        let mut c = PaceCheck::new(0.02);
        assert_eq!(c.observe(0, 0.0), None);
        assert_eq!(c.observe(1, 0.05), None);
        assert_eq!(c.observe(1, 0.05), None);
        assert_eq!(c.observe(2, 0.05), None);
        // A step within the interval: the run of slow frames starts again.
        assert_eq!(c.observe(3, 0.019), None);
        assert_eq!(c.observe(4, 0.11), None);
        assert_eq!(c.observe(6, 0.09), None);
        let b = c.observe(9, 0.12).expect("behind");
        assert_eq!(b.frames, [4, 6, 9]);
        assert_eq!(b.median_step_s, 0.11);
        assert!((b.ratio() - 5.5).abs() < 1e-12);
        assert_eq!(c.observe(10, 0.5), None);
        assert_eq!(c.observe(11, 0.5), None);
        assert_eq!(c.observe(12, 0.5), None);
        // Exactly the interval is not behind.
        let mut c = PaceCheck::new(0.02);
        assert!((1..10).all(|k| c.observe(k, 0.02).is_none()));
    }
}
