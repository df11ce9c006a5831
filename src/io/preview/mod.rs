//! Previews that need no panel: an animated GIF that sweeps the views left to right and
//! back ([`animation`]), and one HTML file that shows the view under the pointer or a
//! finger ([`page`]). Both use the views shrunk to at most [`LONG_SIDE`] pixels on their
//! long side: enough to judge the depth effect on any screen, small enough to mail, and
//! cheap to make beside a render.

pub mod animation;
pub mod page;

use std::path::PathBuf;

use image::imageops;
use image::RgbImage;

/// The longest side of a preview frame, in pixels.
pub const LONG_SIDE: u32 = 512;

#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    #[error("cannot encode {path}: {source}")]
    Gif {
        path: PathBuf,
        source: gif::EncodingError,
    },
    #[error("cannot encode view {view} into {path}: {source}")]
    Jpeg {
        path: PathBuf,
        view: usize,
        source: image::ImageError,
    },
}

/// The size of a preview frame for views of `width`×`height`: the same when its long
/// side is at most [`LONG_SIDE`], else shrunk to it, the aspect kept.
pub fn frame_size(width: u32, height: u32) -> (u32, u32) {
    let long = width.max(height);
    if long <= LONG_SIDE {
        return (width, height);
    }
    let scale = |side: u32| {
        ((u64::from(side) * u64::from(LONG_SIDE) + u64::from(long) / 2) / u64::from(long)).max(1)
            as u32
    };
    (scale(width), scale(height))
}

/// `views` at [`frame_size`], each output pixel the mean of the area it covers, so fine
/// texture averages out instead of aliasing (and at a third of the time of a resampling
/// filter).
pub fn shrink(views: &[RgbImage]) -> Vec<RgbImage> {
    views
        .iter()
        .map(|view| {
            let (w, h) = frame_size(view.width(), view.height());
            if (w, h) == view.dimensions() {
                view.clone()
            } else {
                imageops::thumbnail(view, w, h)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_keep_small_views_and_shrink_large_ones_to_the_long_side() {
        assert_eq!(frame_size(420, 500), (420, 500));
        assert_eq!(frame_size(420, 560), (384, 512));
        assert_eq!(frame_size(1152, 648), (512, 288));
        assert_eq!(frame_size(4096, 2), (512, 1));
        let views = vec![RgbImage::new(1024, 768); 2];
        assert!(shrink(&views).iter().all(|v| v.dimensions() == (512, 384)));
    }
}
