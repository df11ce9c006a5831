//! RGB-D images: the photo on the left and its depth on the right as 8-bit grey, near =
//! white, the form Looking Glass software and many web viewers import. The grey is
//! linear in disparity (1/depth) between the map's nearest and farthest depth, the
//! spacing a viewer's displacement wants, and those two depths are recorded so that
//! the depth can be recovered.

use image::{Rgb, RgbImage};

use crate::depth::DepthMap;
use crate::io::photo::SrgbImage;

/// How the grey of the depth half reads, for run.json and the PNG's metadata.
pub const ENCODING: &str = "8-bit, linear in 1/depth, 255 = depth_near, 0 = depth_far";

/// The depths the grey levels 255 and 0 stand for.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DepthSpan {
    pub near: f64,
    pub far: f64,
}

impl DepthSpan {
    /// The grey level of `depth`: 255 at `near`, 0 at `far`, linear in disparity.
    pub fn grey(&self, depth: f32) -> u8 {
        let (dn, df) = (1.0 / self.near, 1.0 / self.far);
        if dn <= df {
            // A map of one depth: everything is as near as anything.
            return 255;
        }
        let t = (1.0 / f64::from(depth) - df) / (dn - df);
        (t.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

/// `image` beside its `depth` (the same size), and the depths white and black stand for.
pub fn compose(image: &SrgbImage, depth: &DepthMap) -> (RgbImage, DepthSpan) {
    let (w, h) = (image.width(), image.height());
    assert_eq!(
        (depth.width(), depth.height()),
        (w as usize, h as usize),
        "colour and depth sizes differ"
    );
    let [near, far] = depth.range();
    let span = DepthSpan {
        near: f64::from(near),
        far: f64::from(far),
    };
    let colour = image.to_rgb8();
    let out = RgbImage::from_fn(2 * w, h, |x, y| {
        if x < w {
            *colour.get_pixel(x, y)
        } else {
            let g = span.grey(depth.at((x - w) as usize, y as usize));
            Rgb([g, g, g])
        }
    });
    (out, span)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_half_is_white_near_black_far_and_colour_is_kept() {
        let mut image = SrgbImage::new(3, 1);
        image.put(1, 0, [1.0, 0.0, 0.0]);
        let depth = DepthMap::new(3, 1, vec![4.0, 1.0, 2.0]);
        let (rgbd, span) = compose(&image, &depth);
        assert_eq!(rgbd.dimensions(), (6, 1));
        assert_eq!(
            span,
            DepthSpan {
                near: 1.0,
                far: 4.0
            }
        );
        assert_eq!(rgbd.get_pixel(1, 0).0, [255, 0, 0]);
        let grey: Vec<u8> = (3..6).map(|x| rgbd.get_pixel(x, 0).0[0]).collect();
        // Depth 2 is a third of the way from disparity 1/4 to 1.
        assert_eq!(grey, [0, 255, 85]);
    }

    #[test]
    fn a_flat_map_is_all_near() {
        let span = DepthSpan {
            near: 2.0,
            far: 2.0,
        };
        assert_eq!(span.grey(2.0), 255);
    }
}
