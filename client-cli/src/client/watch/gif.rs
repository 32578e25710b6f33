//! The frames of a session's animated GIF, kept within a bound by taking
//! every `stride`-th frame: a fixed stride when the number of frames is
//! known in advance (the demo), else a stride that doubles when the buffer
//! fills (the watcher).

use crate::client::render::Image;

/// GIF frames taken every `stride`-th offered frame. Made with
/// [`GifBuffer::new`], the number stays bounded: past `2 * cap` every other
/// one is dropped and the stride doubles, so the kept frames stay evenly
/// spaced. Made with [`GifBuffer::every`], the stride is fixed and the last
/// of the announced frames is kept too.
#[derive(Debug, Default)]
pub struct GifBuffer {
    /// The bound of a doubling stride (`None`: a fixed stride).
    cap: Option<usize>,
    stride: u64,
    seen: u64,
    /// Index of the last frame that will be offered, when known.
    last: Option<u64>,
    frames: Vec<Image>,
}

impl GifBuffer {
    /// At most about `cap` frames (at least 2) of a stream of unknown
    /// length.
    pub fn new(cap: usize) -> Self {
        Self {
            cap: Some(cap.max(2)),
            stride: 1,
            ..Self::default()
        }
    }

    /// Every `stride`-th of `count` frames (the first included), and the
    /// last of them.
    pub fn every(stride: u64, count: u64) -> Self {
        Self {
            stride: stride.max(1),
            last: count.checked_sub(1),
            ..Self::default()
        }
    }

    /// Whether the next offered frame will be kept (render it only then).
    pub fn wants_next(&self) -> bool {
        self.seen % self.stride == 0 || self.last == Some(self.seen)
    }

    /// Offers the next frame (`None` when it was not rendered because
    /// [`GifBuffer::wants_next`] said no).
    pub fn push(&mut self, img: Option<Image>) {
        if let (true, Some(img)) = (self.wants_next(), img) {
            self.frames.push(img);
            if self.cap.is_some_and(|cap| self.frames.len() >= 2 * cap) {
                let mut k = 0;
                self.frames.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                self.stride *= 2;
            }
        }
        self.seen += 1;
    }

    /// Frame interval of the kept frames in units of offered frames.
    pub fn stride(&self) -> u64 {
        self.stride
    }

    /// The kept frames.
    pub fn frames(&self) -> &[Image] {
        &self.frames
    }
}

/// GIF delay for frames `dt_s` apart in simulation time, hundredths of a
/// second (at least 2: browsers slow down shorter delays).
pub fn gif_delay_cs(dt_s: f64) -> u16 {
    if dt_s.is_finite() && dt_s > 0.0 {
        (dt_s * 100.0).round().clamp(2.0, 500.0) as u16
    } else {
        4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gif_buffer_stays_bounded_and_even() {
        let img = Image::new(2, 2, [0; 3]).unwrap();
        let mut g = GifBuffer::new(10);
        for _ in 0..1000 {
            let want = g.wants_next();
            g.push(want.then(|| img.clone()));
        }
        assert!(g.frames().len() < 20 && g.frames().len() >= 10);
        // 1000 frames with stride s keep ceil(1000 / s) minus the dropped.
        assert_eq!(g.frames().len() as u64, 1000_u64.div_ceil(g.stride()));
    }

    /// A fixed stride over a known count keeps every `stride`-th frame from
    /// the first, and the last: evenly spaced but for the last gap, at most
    /// `ceil(count / stride) + 1` frames.
    #[test]
    fn a_fixed_stride_keeps_the_first_the_last_and_every_strideth() {
        let img = Image::new(2, 2, [0; 3]).unwrap();
        for count in 1..60_u64 {
            for stride in 1..8_u64 {
                let mut g = GifBuffer::every(stride, count);
                let mut kept = Vec::new();
                for i in 0..count {
                    let want = g.wants_next();
                    if want {
                        kept.push(i);
                    }
                    g.push(want.then(|| img.clone()));
                }
                let mut expected: Vec<u64> = (0..count).step_by(stride as usize).collect();
                if (count - 1) % stride != 0 {
                    expected.push(count - 1);
                }
                assert_eq!(kept, expected, "count {count}, stride {stride}");
                assert_eq!(g.frames().len(), kept.len());
                assert_eq!(g.stride(), stride);
            }
        }
    }
}
