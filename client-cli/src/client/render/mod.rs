//! Headless pictures of the simulation: shaded views of the deformed brain with
//! the spatulas and force arrows ([`raster`]), the one composed picture of a
//! simulation state used by the demo, `fissure watch` and the tests
//! ([`frame`]), colour maps ([`colormap`]), text ([`text`]), force and
//! accuracy plots ([`plot`]) and animated GIFs ([`anim`]).
//!
//! Everything draws into an [`Image`] (8-bit sRGB, row-major, top-left origin,
//! `x` to the right and `y` down, in pixels). Nothing needs a GPU, a display or
//! system fonts: the triangle rasteriser is written here (a z-buffer with
//! supersampling, smaller than any 3-D stack, and the GPU is reserved for the
//! solver); plots, their axes and legends and the colour scale are drawn by
//! `plotters` into an RGB buffer; all text uses the DejaVu Sans fonts
//! embedded in the binary (licence in `render/fonts/LICENSE-DejaVu.txt`),
//! rasterised by `ab_glyph` (directly in [`text`], through `plotters` in the
//! charts).

pub mod anim;
pub mod colormap;
pub mod frame;
pub mod plot;
pub mod raster;
pub mod text;

use std::path::{Path, PathBuf};

/// An 8-bit RGB colour (sRGB).
pub type Rgb = [u8; 3];

/// Errors of the rendering stages; each names what is wrong and where.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// An image was asked for with a zero or too large size.
    #[error("invalid image size {width} x {height} px (each side must be 1..=16384)")]
    BadSize { width: u32, height: u32 },
    /// A triangle of a mesh refers to a vertex that does not exist, or a
    /// vertex is not finite.
    #[error("mesh {mesh}: {source}")]
    Surface {
        mesh: usize,
        source: fissure_shared::surface::SurfaceError,
    },
    /// Per-vertex data does not match the number of vertices.
    #[error("mesh {mesh}: {what} has {got} entries for {vertices} vertices")]
    LengthMismatch {
        mesh: usize,
        what: &'static str,
        got: usize,
        vertices: usize,
    },
    /// A value that must be finite is not.
    #[error("{what} is not finite")]
    NonFinite { what: String },
    /// A plot has nothing to draw or a range it cannot show.
    #[error("plot: {0}")]
    Plot(String),
    /// `plotters` failed to draw a chart or a panel.
    #[error("cannot draw the chart: {source}")]
    Chart {
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Animation frames disagree in size or there are none.
    #[error("animation: {0}")]
    Anim(String),
    /// Writing or encoding a PNG failed.
    #[error("cannot write PNG {path}: {source}")]
    Png {
        path: PathBuf,
        source: png::EncodingError,
    },
    /// Writing or encoding a GIF failed.
    #[error("cannot write GIF {path}: {source}")]
    Gif {
        path: PathBuf,
        source: gif::EncodingError,
    },
    /// Creating the output file failed.
    #[error("cannot create {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// An RGB8 image, row-major from the top-left corner.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    width: u32,
    height: u32,
    pixels: Vec<Rgb>,
}

/// Largest accepted side, px.
pub const MAX_SIDE: u32 = 16384;

impl Image {
    /// A `width` x `height` image filled with `colour`.
    pub fn new(width: u32, height: u32, colour: Rgb) -> Result<Self, RenderError> {
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(RenderError::BadSize { width, height });
        }
        Ok(Self {
            width,
            height,
            pixels: vec![colour; width as usize * height as usize],
        })
    }

    /// Width, px.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixels, row-major from the top-left corner.
    pub fn pixels(&self) -> &[Rgb] {
        &self.pixels
    }

    /// The pixels, mutable.
    pub fn pixels_mut(&mut self) -> &mut [Rgb] {
        &mut self.pixels
    }

    /// The pixel at (`x`, `y`), or `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<Rgb> {
        (x < self.width && y < self.height)
            .then(|| self.pixels[y as usize * self.width as usize + x as usize])
    }

    /// Sets the pixel at (`x`, `y`); outside the image nothing happens.
    pub fn put(&mut self, x: i64, y: i64, colour: Rgb) {
        if x >= 0 && y >= 0 && (x as u64) < self.width as u64 && (y as u64) < self.height as u64 {
            self.pixels[y as usize * self.width as usize + x as usize] = colour;
        }
    }

    /// Blends `colour` over the pixel at (`x`, `y`) with opacity `alpha` in
    /// [0, 1] (linear in the 8-bit values); outside the image nothing happens.
    pub fn blend(&mut self, x: i64, y: i64, colour: Rgb, alpha: f32) {
        if alpha <= 0.0 {
            return;
        }
        if x >= 0 && y >= 0 && (x as u64) < self.width as u64 && (y as u64) < self.height as u64 {
            let p = &mut self.pixels[y as usize * self.width as usize + x as usize];
            let a = alpha.min(1.0);
            for c in 0..3 {
                p[c] = (p[c] as f32 + (colour[c] as f32 - p[c] as f32) * a).round() as u8;
            }
        }
    }

    /// The pixels as packed RGB bytes.
    pub fn to_rgb_bytes(&self) -> Vec<u8> {
        self.pixels.iter().flatten().copied().collect()
    }

    /// Builds an image from packed RGB bytes (`3 * width * height` of them).
    pub fn from_rgb_bytes(width: u32, height: u32, bytes: &[u8]) -> Result<Self, RenderError> {
        let mut img = Self::new(width, height, [0; 3])?;
        if bytes.len() != img.pixels.len() * 3 {
            return Err(RenderError::Anim(format!(
                "{} bytes given for a {width} x {height} RGB image",
                bytes.len()
            )));
        }
        for (p, c) in img.pixels.iter_mut().zip(bytes.chunks_exact(3)) {
            *p = [c[0], c[1], c[2]];
        }
        Ok(img)
    }

    /// Encodes the image as an 8-bit RGB PNG in memory.
    pub fn encode_png(&self) -> Result<Vec<u8>, png::EncodingError> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Balanced);
            let mut w = enc.write_header()?;
            w.write_image_data(&self.to_rgb_bytes())?;
            w.finish()?;
        }
        Ok(out)
    }

    /// Writes the image as an 8-bit RGB PNG file.
    pub fn save_png(&self, path: impl AsRef<Path>) -> Result<(), RenderError> {
        let path = path.as_ref();
        let bytes = self.encode_png().map_err(|source| RenderError::Png {
            path: path.into(),
            source,
        })?;
        std::fs::write(path, bytes).map_err(|source| RenderError::Io {
            path: path.into(),
            source,
        })
    }

    /// Copies `src` into this image with its top-left corner at (`x`, `y`),
    /// clipped to this image.
    pub fn blit(&mut self, src: &Image, x: i64, y: i64) {
        for sy in 0..src.height as i64 {
            for sx in 0..src.width as i64 {
                self.put(
                    x + sx,
                    y + sy,
                    src.pixels[(sy * src.width as i64 + sx) as usize],
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_keeps_every_pixel() {
        let mut img = Image::new(7, 5, [10, 20, 30]).unwrap();
        img.put(3, 2, [255, 0, 128]);
        img.put(6, 4, [1, 2, 3]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        img.save_png(&path).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (7, 5));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        let back = Image::from_rgb_bytes(7, 5, &buf[..info.buffer_size()]).unwrap();
        assert_eq!(back, img);
    }

    #[test]
    fn bad_sizes_are_refused() {
        assert!(matches!(
            Image::new(0, 5, [0; 3]),
            Err(RenderError::BadSize { .. })
        ));
        assert!(matches!(
            Image::new(5, MAX_SIDE + 1, [0; 3]),
            Err(RenderError::BadSize { .. })
        ));
    }

    #[test]
    fn out_of_image_writes_are_ignored() {
        let mut img = Image::new(2, 2, [0; 3]).unwrap();
        img.put(-1, 0, [9; 3]);
        img.put(2, 1, [9; 3]);
        img.blend(0, 5, [9; 3], 1.0);
        assert!(img.pixels().iter().all(|p| *p == [0; 3]));
        assert_eq!(img.get(2, 0), None);
    }
}
