//! Animated GIFs from a sequence of [`Image`]s.
//!
//! With the default global palette, one NeuQuant palette of 255 colours is
//! learnt from pixels sampled across all frames (no colour flicker between
//! frames), and each frame after the first stores only the rectangle that
//! changed, with unchanged pixels transparent (index 255) over the previous
//! frame: a turning or slowly deforming model costs a fraction of full
//! frames. The per-frame mode learns a local palette for every frame and
//! stores it whole (better colours when the scene changes a lot).

use super::{Image, RenderError};
use color_quant::NeuQuant;
use std::borrow::Cow;
use std::path::Path;

/// How colours are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PaletteMode {
    /// One palette for the whole animation, frames stored as differences.
    #[default]
    Global,
    /// A palette per frame, frames stored whole.
    PerFrame,
}

/// Options of [`encode_gif`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GifOptions {
    /// Time each frame is shown, in hundredths of a second (GIF's unit;
    /// browsers treat values below 2 as 10).
    pub delay_cs: u16,
    /// Loop forever (else play once).
    pub repeat: bool,
    /// Palette mode.
    pub palette: PaletteMode,
    /// NeuQuant sampling factor, 1 (best, slowest) to 30 (fastest).
    pub quality: i32,
}

impl Default for GifOptions {
    /// 25 frames a second, looping, global palette, sampling factor 10.
    fn default() -> Self {
        Self {
            delay_cs: 4,
            repeat: true,
            palette: PaletteMode::Global,
            quality: 10,
        }
    }
}

/// Index of the transparent colour in the global palette.
const TRANSPARENT: u8 = 255;

/// Memoised nearest-palette lookup on 6 bits per channel.
struct Lookup<'q> {
    quant: &'q NeuQuant,
    table: Vec<u16>,
}

impl<'q> Lookup<'q> {
    fn new(quant: &'q NeuQuant) -> Self {
        Self {
            quant,
            table: vec![u16::MAX; 1 << 18],
        }
    }

    fn index(&mut self, c: [u8; 3]) -> u8 {
        let key = ((c[0] as usize >> 2) << 12) | ((c[1] as usize >> 2) << 6) | (c[2] as usize >> 2);
        let e = &mut self.table[key];
        if *e == u16::MAX {
            *e = self.quant.index_of(&[c[0], c[1], c[2], 255]) as u16;
        }
        *e as u8
    }
}

fn check_frames(frames: &[Image]) -> Result<(u16, u16), RenderError> {
    let first = frames
        .first()
        .ok_or_else(|| RenderError::Anim("no frames".into()))?;
    let (w, h) = (first.width(), first.height());
    if let Some((i, f)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.width() != w || f.height() != h)
    {
        return Err(RenderError::Anim(format!(
            "frame {i} is {} x {} px, frame 0 is {w} x {h} px",
            f.width(),
            f.height()
        )));
    }
    let (Ok(w16), Ok(h16)) = (u16::try_from(w), u16::try_from(h)) else {
        return Err(RenderError::Anim(format!(
            "{w} x {h} px is too large for a GIF"
        )));
    };
    Ok((w16, h16))
}

/// Encodes `frames` (all of one size) as an animated GIF in memory.
pub fn encode_gif(frames: &[Image], opts: &GifOptions) -> Result<Vec<u8>, RenderError> {
    let (w, h) = check_frames(frames)?;
    let gif_err = |source| RenderError::Gif {
        path: "<memory>".into(),
        source,
    };
    let quality = opts.quality.clamp(1, 30);
    let mut out = Vec::new();
    {
        let global_palette;
        let mut quant = None;
        match opts.palette {
            PaletteMode::Global => {
                // Sample up to about 400k pixels spread over all frames.
                let total: usize = frames.iter().map(|f| f.pixels().len()).sum();
                let stride = (total / 400_000).max(1);
                let mut samples = Vec::with_capacity(4 * (total / stride + 1));
                let mut k = 0usize;
                for f in frames {
                    for p in f.pixels() {
                        if k % stride == 0 {
                            samples.extend_from_slice(&[p[0], p[1], p[2], 255]);
                        }
                        k += 1;
                    }
                }
                let q = NeuQuant::new(quality, 255, &samples);
                let mut pal = q.color_map_rgb();
                pal.resize(256 * 3, 0);
                global_palette = pal;
                quant = Some(q);
            }
            PaletteMode::PerFrame => global_palette = Vec::new(),
        }
        let mut enc = gif::Encoder::new(&mut out, w, h, &global_palette).map_err(gif_err)?;
        enc.set_repeat(if opts.repeat {
            gif::Repeat::Infinite
        } else {
            gif::Repeat::Finite(0)
        })
        .map_err(gif_err)?;
        match quant {
            Some(q) => {
                let mut lookup = Lookup::new(&q);
                let (wu, hu) = (w as usize, h as usize);
                let mut prev: Vec<u8> = Vec::new();
                let mut cur = vec![0u8; wu * hu];
                for (fi, f) in frames.iter().enumerate() {
                    for (d, p) in cur.iter_mut().zip(f.pixels()) {
                        *d = lookup.index(*p);
                    }
                    let mut frame = gif::Frame {
                        delay: opts.delay_cs,
                        dispose: gif::DisposalMethod::Keep,
                        ..gif::Frame::default()
                    };
                    if fi == 0 {
                        frame.width = w;
                        frame.height = h;
                        frame.buffer = Cow::Borrowed(&cur);
                        enc.write_frame(&frame).map_err(gif_err)?;
                    } else {
                        // Bounding box of the changed pixels.
                        let (mut x0, mut y0, mut x1, mut y1) = (wu, hu, 0usize, 0usize);
                        for y in 0..hu {
                            let row = y * wu;
                            for x in 0..wu {
                                if cur[row + x] != prev[row + x] {
                                    x0 = x0.min(x);
                                    x1 = x1.max(x + 1);
                                    y0 = y0.min(y);
                                    y1 = y1.max(y + 1);
                                }
                            }
                        }
                        if x0 >= x1 {
                            (x0, y0, x1, y1) = (0, 0, 1, 1);
                        }
                        let mut buf = Vec::with_capacity((x1 - x0) * (y1 - y0));
                        for y in y0..y1 {
                            let row = y * wu;
                            for x in x0..x1 {
                                let c = cur[row + x];
                                buf.push(if c == prev[row + x] { TRANSPARENT } else { c });
                            }
                        }
                        frame.left = x0 as u16;
                        frame.top = y0 as u16;
                        frame.width = (x1 - x0) as u16;
                        frame.height = (y1 - y0) as u16;
                        frame.transparent = Some(TRANSPARENT);
                        frame.buffer = Cow::Owned(buf);
                        enc.write_frame(&frame).map_err(gif_err)?;
                    }
                    std::mem::swap(&mut prev, &mut cur);
                    cur.resize(wu * hu, 0);
                }
            }
            None => {
                for f in frames {
                    let rgb = f.to_rgb_bytes();
                    let mut frame = gif::Frame::from_rgb_speed(w, h, &rgb, quality);
                    frame.delay = opts.delay_cs;
                    enc.write_frame(&frame).map_err(gif_err)?;
                }
            }
        }
    }
    Ok(out)
}

/// Encodes `frames` as an animated GIF file at `path`.
pub fn save_gif(
    frames: &[Image],
    path: impl AsRef<Path>,
    opts: &GifOptions,
) -> Result<(), RenderError> {
    let path = path.as_ref();
    let bytes = encode_gif(frames, opts).map_err(|e| match e {
        RenderError::Gif { source, .. } => RenderError::Gif {
            path: path.into(),
            source,
        },
        other => other,
    })?;
    std::fs::write(path, bytes).map_err(|source| RenderError::Io {
        path: path.into(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disc moving across a gradient, `n` frames of `w` x `h`.
    fn frames(n: usize, w: u32, h: u32) -> Vec<Image> {
        (0..n)
            .map(|i| {
                let mut img = Image::new(w, h, [240, 240, 240]).unwrap();
                for y in 0..h as i64 {
                    for x in 0..30 {
                        img.put(x, y, [(y * 255 / h as i64) as u8, 60, 120]);
                    }
                }
                let cx = 40.0 + (w as f64 - 80.0) * i as f64 / n as f64;
                let cy = h as f64 / 2.0;
                for y in 0..h as i64 {
                    for x in 0..w as i64 {
                        if (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) <= 15.0 {
                            img.put(x, y, [200, 40, 40]);
                        }
                    }
                }
                img
            })
            .collect()
    }

    /// Decodes a GIF, composing frames as a viewer does; returns the frames.
    fn decode(bytes: &[u8]) -> (u16, u16, Vec<Vec<[u8; 3]>>) {
        let mut opts = gif::DecodeOptions::new();
        opts.set_color_output(gif::ColorOutput::RGBA);
        let mut dec = opts.read_info(bytes).unwrap();
        let (w, h) = (dec.width(), dec.height());
        let mut canvas = vec![[0u8; 3]; w as usize * h as usize];
        let mut out = Vec::new();
        while let Some(f) = dec.read_next_frame().unwrap() {
            for y in 0..f.height as usize {
                for x in 0..f.width as usize {
                    let s = &f.buffer[4 * (y * f.width as usize + x)..][..4];
                    if s[3] > 0 {
                        canvas[(y + f.top as usize) * w as usize + x + f.left as usize] =
                            [s[0], s[1], s[2]];
                    }
                }
            }
            out.push(canvas.clone());
        }
        (w, h, out)
    }

    fn max_error(a: &[[u8; 3]], b: &[[u8; 3]]) -> (i32, f64) {
        let mut max = 0;
        let mut sum = 0.0;
        for (p, q) in a.iter().zip(b) {
            for c in 0..3 {
                let d = (p[c] as i32 - q[c] as i32).abs();
                max = max.max(d);
                sum += d as f64;
            }
        }
        (max, sum / (3 * a.len()) as f64)
    }

    #[test]
    fn global_palette_gif_decodes_to_the_frames() {
        let src = frames(12, 160, 90);
        let bytes = encode_gif(&src, &GifOptions::default()).unwrap();
        let (w, h, dec) = decode(&bytes);
        assert_eq!((w, h), (160, 90));
        assert_eq!(dec.len(), 12);
        for (i, (d, s)) in dec.iter().zip(&src).enumerate() {
            let (max, mean) = max_error(d, s.pixels());
            assert!(mean < 3.0 && max < 60, "frame {i}: mean {mean}, max {max}");
        }
        // Difference frames make it far smaller than 12 whole frames.
        let single = encode_gif(&src[..1], &GifOptions::default()).unwrap();
        assert!(
            bytes.len() < 6 * single.len(),
            "{} vs {}",
            bytes.len(),
            single.len()
        );
    }

    #[test]
    fn per_frame_palette_gif_decodes_to_the_frames() {
        let src = frames(5, 120, 80);
        let opts = GifOptions {
            palette: PaletteMode::PerFrame,
            ..GifOptions::default()
        };
        let bytes = encode_gif(&src, &opts).unwrap();
        let (w, h, dec) = decode(&bytes);
        assert_eq!((w, h, dec.len()), (120, 80, 5));
        let (_, mean) = max_error(&dec[4], src[4].pixels());
        assert!(mean < 3.0);
    }

    #[test]
    fn identical_frames_and_bad_input() {
        let img = Image::new(20, 10, [1, 2, 3]).unwrap();
        let bytes = encode_gif(
            &[img.clone(), img.clone(), img.clone()],
            &GifOptions::default(),
        )
        .unwrap();
        assert_eq!(decode(&bytes).2.len(), 3);
        assert!(matches!(
            encode_gif(&[], &GifOptions::default()),
            Err(RenderError::Anim(_))
        ));
        let other = Image::new(21, 10, [0; 3]).unwrap();
        assert!(matches!(
            encode_gif(&[img, other], &GifOptions::default()),
            Err(RenderError::Anim(_))
        ));
    }

    #[test]
    fn save_gif_writes_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.gif");
        save_gif(&frames(3, 64, 48), &path, &GifOptions::default()).unwrap();
        let (_, _, dec) = decode(&std::fs::read(&path).unwrap());
        assert_eq!(dec.len(), 3);
    }
}
