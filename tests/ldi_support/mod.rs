//! Synthetic scenes for the LDI tests: flat-coloured occluders (pure red or green) in
//! front of a wall whose texture has no red, so the red channel of a view measures
//! exactly how much of a pixel shows the red occluder.
// Each test binary uses a different part of this module.
#![allow(dead_code)]

use reshader::depth::DepthMap;
use reshader::io::photo::SrgbImage;
use reshader::relocate::ldi::{Ldi, LdiConfig, Rendered};
use reshader::views::{Intrinsics, ViewCamera};

pub const W: usize = 64;
pub const H: usize = 48;
pub const RED: [f32; 3] = [1.0, 0.0, 0.0];
pub const GREEN: [f32; 3] = [0.0, 1.0, 0.0];

pub fn camera() -> Intrinsics {
    Intrinsics::from_hfov(W as u32, H as u32, 60.0)
}

/// The wall's colour at (x, y): blue with a cyan stripe texture.
pub fn wall(x: usize, y: usize) -> [f32; 3] {
    [0.0, 0.1 + 0.3 * (((x / 3 + y / 5) % 2) as f32), 0.8]
}

/// A scene: colours and depth, built up by painting rectangles over a wall.
pub struct Scene {
    pub colours: SrgbImage,
    pub depth: Vec<f32>,
}

impl Scene {
    pub fn wall(depth: f32) -> Self {
        let mut colours = SrgbImage::new(W as u32, H as u32);
        for y in 0..H {
            for x in 0..W {
                colours.put(x as u32, y as u32, wall(x, y));
            }
        }
        Self {
            colours,
            depth: vec![depth; W * H],
        }
    }

    /// Paints [x0, x1) × [y0, y1) with `colour` at `depth`.
    pub fn rect(
        mut self,
        x: std::ops::Range<usize>,
        y: std::ops::Range<usize>,
        colour: [f32; 3],
        depth: f32,
    ) -> Self {
        for yy in y {
            for xx in x.clone() {
                self.colours.put(xx as u32, yy as u32, colour);
                self.depth[yy * W + xx] = depth;
            }
        }
        self
    }

    pub fn depth_map(&self) -> DepthMap {
        DepthMap::new(W, H, self.depth.clone())
    }

    pub fn build(&self, config: &LdiConfig, reach: f64) -> Ldi {
        Ldi::build(&self.colours, &self.depth_map(), &camera(), config, reach).unwrap()
    }
}

pub fn view(tx: f64, focus: f64) -> ViewCamera {
    ViewCamera::off_axis(&camera(), [tx, 0.0, 0.0], focus).unwrap()
}

/// Horizontal image shift of a point at `depth` seen from `tx` with the zero-parallax
/// plane at `focus`.
pub fn shift(tx: f64, depth: f64, focus: f64) -> f64 {
    -camera().fx * tx * (1.0 / depth - 1.0 / focus)
}

pub fn render(ldi: &Ldi, scene: &Scene, tx: f64, focus: f64) -> Rendered {
    ldi.render_detailed(&scene.colours, &view(tx, focus))
        .unwrap()
}

/// The red channel of row `y`.
pub fn red_row(image: &SrgbImage, y: usize) -> Vec<f32> {
    (0..W).map(|x| image.get(x as u32, y as u32)[0]).collect()
}
