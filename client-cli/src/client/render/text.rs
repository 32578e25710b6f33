//! Antialiased text for titles, labels and legends.
//!
//! Glyphs come from DejaVu Sans (regular and bold), embedded in the binary so
//! that pictures render the same on a headless server with no fonts installed
//! (licence: `render/fonts/LICENSE-DejaVu.txt`), and are rasterised by
//! `ab_glyph` into coverage that is blended over the image. Sizes are in pixels
//! (the font's ascent minus descent).

use super::{Image, Rgb};
use ab_glyph::{Font, FontRef, GlyphId, PxScale, ScaleFont, point};
use std::sync::OnceLock;

pub(crate) static REGULAR_BYTES: &[u8] = include_bytes!("fonts/DejaVuSans.ttf");
pub(crate) static BOLD_BYTES: &[u8] = include_bytes!("fonts/DejaVuSans-Bold.ttf");

/// Font weight.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Weight {
    /// DejaVu Sans.
    #[default]
    Regular,
    /// DejaVu Sans Bold.
    Bold,
}

fn font(weight: Weight) -> &'static FontRef<'static> {
    static REGULAR: OnceLock<FontRef<'static>> = OnceLock::new();
    static BOLD: OnceLock<FontRef<'static>> = OnceLock::new();
    let (cell, bytes) = match weight {
        Weight::Regular => (&REGULAR, REGULAR_BYTES),
        Weight::Bold => (&BOLD, BOLD_BYTES),
    };
    // The font is part of the binary and checked by a test; it cannot fail at
    // run time unless the binary itself is corrupt.
    cell.get_or_init(|| FontRef::try_from_slice(bytes).expect("embedded DejaVu font parses"))
}

/// Horizontal placement of text relative to its anchor point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HAlign {
    /// The anchor is at the start of the text.
    #[default]
    Left,
    /// The anchor is at the middle.
    Center,
    /// The anchor is at the end.
    Right,
}

/// Vertical placement of text relative to its anchor point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VAlign {
    /// The anchor is at the top of the line (ascent).
    #[default]
    Top,
    /// The anchor is halfway between ascent and descent.
    Middle,
    /// The anchor is on the baseline.
    Baseline,
    /// The anchor is at the bottom of the line (descent).
    Bottom,
}

/// How to draw a piece of text.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextStyle {
    /// Size, px.
    pub size: f32,
    /// Colour.
    pub colour: Rgb,
    /// Weight.
    pub weight: Weight,
    /// Horizontal alignment.
    pub h: HAlign,
    /// Vertical alignment.
    pub v: VAlign,
}

impl TextStyle {
    /// Dark grey regular text of `size` px, anchored at its top-left.
    pub fn new(size: f32) -> Self {
        Self {
            size,
            colour: [30, 30, 30],
            weight: Weight::Regular,
            h: HAlign::Left,
            v: VAlign::Top,
        }
    }

    /// The same style in bold.
    pub fn bold(mut self) -> Self {
        self.weight = Weight::Bold;
        self
    }

    /// The same style in another colour.
    pub fn colour(mut self, colour: Rgb) -> Self {
        self.colour = colour;
        self
    }

    /// The same style with another alignment.
    pub fn align(mut self, h: HAlign, v: VAlign) -> Self {
        self.h = h;
        self.v = v;
        self
    }
}

/// The extent of a line of text, px.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extent {
    /// Advance width.
    pub width: f32,
    /// Height above the baseline.
    pub ascent: f32,
    /// Depth below the baseline (positive).
    pub descent: f32,
}

/// Glyph ids and pen positions of a line laid out from x = 0.
fn layout(text: &str, style: &TextStyle) -> (Vec<(GlyphId, f32)>, Extent) {
    let f = font(style.weight);
    let scaled = f.as_scaled(PxScale::from(style.size.max(1.0)));
    let mut caret = 0.0;
    let mut prev: Option<GlyphId> = None;
    let mut glyphs = Vec::with_capacity(text.len());
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            caret += scaled.kern(p, id);
        }
        glyphs.push((id, caret));
        caret += scaled.h_advance(id);
        prev = Some(id);
    }
    (
        glyphs,
        Extent {
            width: caret,
            ascent: scaled.ascent(),
            descent: -scaled.descent(),
        },
    )
}

/// The extent of `text` drawn with `style`.
pub fn measure(text: &str, style: &TextStyle) -> Extent {
    layout(text, style).1
}

/// Offset of the top-left of the line box from the anchor.
fn anchor_offset(ext: &Extent, style: &TextStyle) -> (f32, f32) {
    let dx = match style.h {
        HAlign::Left => 0.0,
        HAlign::Center => -0.5 * ext.width,
        HAlign::Right => -ext.width,
    };
    let dy = match style.v {
        VAlign::Top => 0.0,
        VAlign::Middle => -0.5 * (ext.ascent + ext.descent),
        VAlign::Baseline => -ext.ascent,
        VAlign::Bottom => -(ext.ascent + ext.descent),
    };
    (dx, dy)
}

/// Calls `put(x, y, coverage)` for each covered pixel of the line whose box's
/// top-left corner is at (`x0`, `y0`) in unrotated text coordinates.
fn rasterise(text: &str, style: &TextStyle, x0: f32, y0: f32, mut put: impl FnMut(i64, i64, f32)) {
    let (glyphs, ext) = layout(text, style);
    let f = font(style.weight);
    let scale = PxScale::from(style.size.max(1.0));
    for (id, x) in glyphs {
        let g = id.with_scale_and_position(scale, point(x0 + x, y0 + ext.ascent));
        if let Some(outlined) = f.outline_glyph(g) {
            let bb = outlined.px_bounds();
            outlined
                .draw(|gx, gy, c| put(bb.min.x as i64 + gx as i64, bb.min.y as i64 + gy as i64, c));
        }
    }
}

/// Draws one line of `text` anchored at (`x`, `y`) px; returns its extent.
pub fn draw_text(img: &mut Image, text: &str, x: f32, y: f32, style: &TextStyle) -> Extent {
    let ext = measure(text, style);
    let (dx, dy) = anchor_offset(&ext, style);
    // Snap the box to whole pixels so that stems stay crisp.
    let (x0, y0) = ((x + dx).round(), (y + dy).round());
    rasterise(text, style, x0, y0, |px, py, c| {
        img.blend(px, py, style.colour, c)
    });
    ext
}

/// Draws `text` rotated 90 degrees counter-clockwise (reading upwards), as for
/// a vertical axis title. The alignment refers to the rotated text: `h` along
/// the reading direction (upwards), `v` across it; returns the unrotated
/// extent.
pub fn draw_text_vertical(
    img: &mut Image,
    text: &str,
    x: f32,
    y: f32,
    style: &TextStyle,
) -> Extent {
    let ext = measure(text, style);
    let (dx, dy) = anchor_offset(&ext, style);
    // Unrotated coordinates (u along the text, v down across it), relative to
    // the anchor; rotation maps (u, v) to image (x + v, y - u).
    let (u0, v0) = (dx.round(), dy.round());
    let (ax, ay) = (x.round() as i64, y.round() as i64);
    rasterise(text, style, u0, v0, |u, v, c| {
        img.blend(ax + v, ay - u - 1, style.colour, c)
    });
    ext
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fonts_parse_and_text_has_ink_where_placed() {
        for w in [Weight::Regular, Weight::Bold] {
            let mut img = Image::new(200, 40, [255; 3]).unwrap();
            let style = TextStyle {
                weight: w,
                ..TextStyle::new(20.0)
            };
            let ext = draw_text(&mut img, "Force 1.5 N", 10.0, 5.0, &style);
            assert!(ext.width > 80.0 && ext.width < 150.0, "width {}", ext.width);
            let dark: Vec<(u32, u32)> = (0..40)
                .flat_map(|y| (0..200).map(move |x| (x, y)))
                .filter(|&(x, y)| img.get(x, y).unwrap()[0] < 128)
                .collect();
            assert!(dark.len() > 100);
            // All ink lies inside the laid-out box (with a pixel of slack).
            for (x, y) in dark {
                assert!(x as f32 >= 9.0 && (x as f32) <= 11.0 + ext.width, "x {x}");
                assert!(
                    y as f32 >= 4.0 && (y as f32) <= 6.0 + ext.ascent + ext.descent,
                    "y {y}"
                );
            }
        }
    }

    #[test]
    fn alignment_moves_the_text() {
        let style = TextStyle::new(16.0).align(HAlign::Right, VAlign::Bottom);
        let mut img = Image::new(100, 40, [255; 3]).unwrap();
        draw_text(&mut img, "abc", 90.0, 35.0, &style);
        let ink_x: Vec<u32> = (0..40)
            .flat_map(|y| (0..100).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get(x, y).unwrap()[0] < 128)
            .map(|(x, _)| x)
            .collect();
        assert!(!ink_x.is_empty());
        assert!(*ink_x.iter().max().unwrap() <= 91);
        assert!(*ink_x.iter().min().unwrap() > 50);
    }

    #[test]
    fn vertical_text_is_taller_than_wide() {
        let mut img = Image::new(40, 200, [255; 3]).unwrap();
        let style = TextStyle::new(16.0).align(HAlign::Center, VAlign::Middle);
        draw_text_vertical(&mut img, "Force (N)", 20.0, 100.0, &style);
        let ink: Vec<(u32, u32)> = (0..200)
            .flat_map(|y| (0..40).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get(x, y).unwrap()[0] < 128)
            .collect();
        let (xs, ys): (Vec<u32>, Vec<u32>) = ink.into_iter().unzip();
        let w = xs.iter().max().unwrap() - xs.iter().min().unwrap();
        let h = ys.iter().max().unwrap() - ys.iter().min().unwrap();
        assert!(h > 3 * w, "w {w} h {h}");
        // Centred on the anchor within a few pixels.
        let cy = (ys.iter().max().unwrap() + ys.iter().min().unwrap()) as f32 / 2.0;
        assert!((cy - 100.0).abs() < 4.0, "cy {cy}");
    }
}
