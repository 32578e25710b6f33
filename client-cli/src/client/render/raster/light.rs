//! How a view is lit and finished: lights fixed in the view frame, the
//! background, and the options of a render (size, supersampling).

use super::super::Rgb;
use nalgebra::Vector3;

/// A directional light fixed in the view frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Direction towards the light in view space (x right, y up, z towards
    /// the viewer); need not be normalised.
    pub direction: Vector3<f64>,
    /// Diffuse intensity.
    pub intensity: f64,
}

/// Lights and material constants.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// Ambient term.
    pub ambient: f64,
    /// Directional lights; the first one also makes the specular highlight.
    pub lights: Vec<Light>,
    /// Specular exponent (an integer, so that the highlight costs a few
    /// multiplications a pixel).
    pub shininess: i32,
    /// Factor on the base colour of faces seen from behind, in [0, 1].
    pub back_factor: f64,
}

impl Default for Lighting {
    /// A key light from the upper left, a weaker fill from the right and a
    /// soft ambient term.
    fn default() -> Self {
        Self {
            ambient: 0.46,
            lights: vec![
                Light {
                    direction: Vector3::new(-0.45, 0.65, 0.75),
                    intensity: 0.48,
                },
                Light {
                    direction: Vector3::new(0.7, -0.1, 0.5),
                    intensity: 0.18,
                },
            ],
            shininess: 32,
            back_factor: 0.7,
        }
    }
}

/// What lies behind the meshes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Background {
    /// One colour.
    Solid(Rgb),
    /// A vertical gradient from `top` to `bottom`.
    Gradient {
        /// Colour of the top row.
        top: Rgb,
        /// Colour of the bottom row.
        bottom: Rgb,
    },
}

impl Background {
    /// Colour of output row `y` of an image `height` rows high.
    pub fn at(&self, y: usize, height: u32) -> Rgb {
        match *self {
            Background::Solid(c) => c,
            Background::Gradient { top, bottom } => {
                let t = y as f64 / (height.max(2) - 1) as f64;
                [0, 1, 2]
                    .map(|i| (top[i] as f64 + (bottom[i] as f64 - top[i] as f64) * t).round() as u8)
            }
        }
    }
}

impl Default for Background {
    fn default() -> Self {
        Background::Gradient {
            top: [250, 251, 253],
            bottom: [214, 220, 228],
        }
    }
}

/// Options of a [`Renderer`].
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Output width, px.
    pub width: u32,
    /// Output height, px.
    pub height: u32,
    /// Supersampling factor per axis (1 = none, 2 = 2 x 2 samples, up to 4).
    pub supersample: u32,
    /// Background.
    pub background: Background,
    /// Lighting.
    pub lighting: Lighting,
}

impl RenderOptions {
    /// `width` x `height` with 2 x 2 supersampling, the default background
    /// and lighting.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            supersample: 2,
            background: Background::default(),
            lighting: Lighting::default(),
        }
    }

    /// Aspect ratio width / height.
    pub fn aspect(&self) -> f64 {
        self.width as f64 / self.height as f64
    }
}
