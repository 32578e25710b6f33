//! The frames of a session's animated GIF, kept within a bound by taking
//! every `stride`-th frame (the stride doubles when the buffer fills).

use crate::client::render::Image;

/// GIF frames with a bound on their number: past `2 * cap` every other one
/// is dropped and the stride doubles, so the kept frames stay evenly spaced.
#[derive(Debug, Default)]
pub struct GifBuffer {
    cap: usize,
    stride: u64,
    seen: u64,
    frames: Vec<Image>,
}

impl GifBuffer {
    /// At most about `cap` frames (at least 2).
    pub fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(2),
            stride: 1,
            seen: 0,
            frames: Vec::new(),
        }
    }

    /// Whether the next offered frame will be kept (render it only then).
    pub fn wants_next(&self) -> bool {
        self.seen % self.stride == 0
    }

    /// Offers the next frame (`None` when it was not rendered because
    /// [`GifBuffer::wants_next`] said no).
    pub fn push(&mut self, img: Option<Image>) {
        if let (true, Some(img)) = (self.wants_next(), img) {
            self.frames.push(img);
            if self.frames.len() >= 2 * self.cap {
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
}
