//! Relocation as a lookup: which source pixels each pixel of a view shows.
//!
//! With the depth map and the camera fixed, a relocated view is a fixed function of the
//! colours: each of its pixels averages the colours of a few source pixels (its
//! subsamples), chosen by the geometry alone. `live` reuses one depth map for many
//! camera frames; rebuilding and rasterising the layered depth image for every frame
//! costs about 3 ms per view, applying its maps a fraction of that.

use image::RgbImage;

use crate::io::photo::SrgbImage;
use crate::relocate::RelocateError;

/// A subsample that shows nothing (a view that sees none of the scene there): black.
pub const NO_SOURCE: u32 = u32::MAX;

/// One view's lookup: per view pixel, the source pixel it shows, or, where its
/// subsamples show different ones (silhouettes, a few percent of pixels), all of them.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewMap {
    width: u32,
    height: u32,
    source_size: (u32, u32),
    taps: usize,
    /// A source index, [`NO_SOURCE`], or [`MIXED`] | k: the taps `mixed[k·taps..]`.
    pixels: Vec<u32>,
    mixed: Vec<u32>,
}

/// Marks a pixel whose subsamples differ (source indices stay below it).
const MIXED: u32 = 1 << 31;

/// Steps of one 8-bit level in a [`ShadingChange`].
const STEPS_PER_LEVEL: i32 = 64;

/// A view's reshading kept as the change it made to the photo, per subpixel in 1/64ths
/// of an 8-bit level, in the source camera's frame: later frames get the same change.
#[derive(Clone, Debug, PartialEq)]
pub struct ShadingChange {
    size: (u32, u32),
    steps: Vec<i16>,
}

impl ShadingChange {
    /// `reshaded` − `photo`; both the same size.
    pub fn between(photo: &SrgbImage, reshaded: &SrgbImage) -> Result<Self, RelocateError> {
        let size = (photo.width(), photo.height());
        let got = (reshaded.width(), reshaded.height());
        if got != size {
            return Err(RelocateError::MapSize {
                what: "reshaded image",
                expected: size,
                got,
            });
        }
        let scale = 255.0 * STEPS_PER_LEVEL as f32;
        let limit = f32::from(i16::MAX);
        let steps = photo
            .data()
            .iter()
            .zip(reshaded.data())
            .map(|(&p, &r)| {
                ((r.clamp(0.0, 1.0) - p) * scale)
                    .round()
                    .clamp(-limit, limit) as i16
            })
            .collect();
        Ok(Self { size, steps })
    }
}

impl ShadingChange {
    /// Heap bytes the change holds.
    pub fn bytes(&self) -> usize {
        self.steps.len() * std::mem::size_of::<i16>()
    }
}

impl ViewMap {
    /// A `width`×`height` view of a `source_size` image from `taps` source indices per
    /// pixel (or [`NO_SOURCE`]), row-major.
    ///
    /// # Panics
    /// If `sources` does not hold `taps` entries per pixel, or an entry other than
    /// [`NO_SOURCE`] lies outside the source image: both are the builder's bugs.
    pub fn new(
        (width, height): (u32, u32),
        source_size: (u32, u32),
        taps: usize,
        sources: &[u32],
    ) -> Self {
        let taps = taps.max(1);
        let pixels = width as usize * height as usize;
        assert_eq!(sources.len(), pixels * taps, "one entry per tap and pixel");
        let source_pixels = u64::from(source_size.0) * u64::from(source_size.1);
        assert!(
            source_pixels <= u64::from(MIXED),
            "source image too large for a map"
        );
        assert!(
            sources
                .iter()
                .all(|&s| s == NO_SOURCE || u64::from(s) < source_pixels),
            "a source index lies outside the source image"
        );
        let mut mixed = Vec::new();
        let pixels = sources
            .chunks_exact(taps)
            .map(|t| {
                if t.iter().all(|&s| s == t[0]) {
                    t[0]
                } else {
                    let k = (mixed.len() / taps) as u32;
                    mixed.extend_from_slice(t);
                    MIXED | k
                }
            })
            .collect();
        Self {
            width,
            height,
            source_size,
            taps,
            pixels,
            mixed,
        }
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Heap bytes the map holds.
    pub fn bytes(&self) -> usize {
        (self.pixels.len() + self.mixed.len()) * std::mem::size_of::<u32>()
    }

    /// The view of `image` (8-bit, in the source camera's frame), with `change` added to
    /// every source subpixel first when given, into `out` (resized if it must be).
    pub fn apply(
        &self,
        image: &RgbImage,
        change: Option<&ShadingChange>,
        out: &mut RgbImage,
    ) -> Result<(), RelocateError> {
        let check = |what, got| {
            if got == self.source_size {
                Ok(())
            } else {
                Err(RelocateError::MapSize {
                    what,
                    expected: self.source_size,
                    got,
                })
            }
        };
        check("frame", image.dimensions())?;
        if let Some(c) = change {
            check("shading change", c.size)?;
        }
        if out.dimensions() != (self.width, self.height) {
            *out = RgbImage::new(self.width, self.height);
        }
        let src = image.as_raw();
        let taps = self.taps as i32;
        let half = taps * STEPS_PER_LEVEL / 2;
        let top = 255 * STEPS_PER_LEVEL;
        let shifted = |at: usize| -> i32 {
            let shift = change.map_or(0, |ch| i32::from(ch.steps[at]));
            (i32::from(src[at]) * STEPS_PER_LEVEL + shift).clamp(0, top)
        };
        for (px, &p) in out.chunks_exact_mut(3).zip(&self.pixels) {
            if p == NO_SOURCE {
                px.fill(0);
            } else if p & MIXED == 0 {
                let at = 3 * p as usize;
                for (c, v) in px.iter_mut().enumerate() {
                    *v = ((shifted(at + c) + STEPS_PER_LEVEL / 2) / STEPS_PER_LEVEL) as u8;
                }
            } else {
                let k = (p & !MIXED) as usize * self.taps;
                let mut sum = [0i32; 3];
                for &s in self.mixed[k..k + self.taps]
                    .iter()
                    .filter(|&&s| s != NO_SOURCE)
                {
                    let at = 3 * s as usize;
                    for (c, total) in sum.iter_mut().enumerate() {
                        *total += shifted(at + c);
                    }
                }
                for c in 0..3 {
                    px[c] = ((sum[c] + half) / (taps * STEPS_PER_LEVEL)) as u8;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn photo() -> RgbImage {
        RgbImage::from_fn(3, 2, |x, y| image::Rgb([(40 * x + 10 * y) as u8, 200, 255]))
    }

    #[test]
    fn averages_the_taps_and_shows_black_where_nothing_is_seen() {
        // Two pixels: the first averages source pixels 0 and 2, the second sees nothing.
        let map = ViewMap::new((2, 1), (3, 2), 2, &[0, 2, NO_SOURCE, NO_SOURCE]);
        let mut out = RgbImage::new(0, 0);
        map.apply(&photo(), None, &mut out).unwrap();
        assert_eq!(out.as_raw(), &[40, 200, 255, 0, 0, 0]);
    }

    #[test]
    fn adds_the_shading_change_and_clips_at_white() {
        let p = photo();
        let mut brighter = SrgbImage::from_rgb8(&p);
        let lifted: Vec<f32> = brighter.data().iter().map(|v| v + 10.0 / 255.0).collect();
        for (i, v) in lifted.chunks_exact(3).enumerate() {
            brighter.put(i as u32 % 3, i as u32 / 3, [v[0], v[1], v[2]]);
        }
        let change = ShadingChange::between(&SrgbImage::from_rgb8(&p), &brighter).unwrap();
        let map = ViewMap::new((1, 1), (3, 2), 1, &[4]);
        let mut out = RgbImage::new(1, 1);
        map.apply(&p, Some(&change), &mut out).unwrap();
        // Source pixel 4 is (1, 1): 50, 200, 255 before the change.
        assert_eq!(out.as_raw(), &[60, 210, 255]);
    }

    #[test]
    fn refuses_a_frame_of_another_size() {
        let map = ViewMap::new((1, 1), (3, 2), 1, &[0]);
        let err = map
            .apply(&RgbImage::new(2, 2), None, &mut RgbImage::new(1, 1))
            .unwrap_err();
        assert_eq!(
            err,
            RelocateError::MapSize {
                what: "frame",
                expected: (3, 2),
                got: (2, 2)
            }
        );
    }
}
