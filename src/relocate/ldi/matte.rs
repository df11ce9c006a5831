//! Soft silhouettes. The outermost pixel of a foreground object is usually a mix of the
//! object and of the background behind it (lens and sensor spread every edge over a
//! pixel or so). Cut by depth alone, it moves with the object and carries its share of
//! the old background along: a rim of the wrong colour around the object wherever a
//! view sees it against another background.
//!
//! Each near-side pixel of a cut gets an alpha, the share of it that is foreground,
//! estimated from the colours one pixel inwards (the object) and one or two pixels
//! outwards (the background): the pixel's position along the line between them. A view
//! draws such a pixel over whatever lies behind it there, exchanging the background
//! share: `p + (1 − α)·(behind − beneath)`, where `beneath` is the band sample under the
//! pixel. That band sample takes its colour from the background pixel the alpha was
//! measured against (instead of the one patch synthesis chose), so that the share taken
//! out is the background the alpha assumed, not a texture copied from elsewhere that
//! would speckle the edge. At the input camera what lies behind the pixel is that band
//! sample, so the photo is reproduced exactly.

use super::band::{Band, NONE};
use super::edges::Cuts;

/// Colour difference (Euclidean, colours in [0, 1]) between the two sides under which
/// an edge keeps its hard silhouette: the alpha of a pixel between two similar colours
/// is noise, and swapping a similar background changes nothing visible.
const MIN_CONTRAST: f32 = 0.08;

/// Alphas above this draw the pixel opaque: what it would exchange is below a level.
const OPAQUE: f32 = 0.98;

/// A foreground pixel drawn with partial coverage.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Soft {
    /// The pixel (its front sample).
    pub sample: u32,
    /// The band sample under it.
    pub beneath: u32,
    /// Its foreground share.
    pub alpha: f32,
}

/// The soft pixels of an LDI, and which front samples they are.
#[derive(Default)]
pub(super) struct Mattes {
    pub soft: Vec<Soft>,
    /// Per front sample: its index in `soft`, or [`NONE`].
    pub index: Vec<u32>,
}

impl Mattes {
    pub fn is_empty(&self) -> bool {
        self.soft.is_empty()
    }

    /// Whether sample `s` is drawn in the soft pass rather than with the opaque ones.
    pub fn is_soft(&self, s: u32) -> bool {
        self.index.get(s as usize).is_some_and(|&i| i != NONE)
    }
}

/// The alphas of the near-side pixels of every cut of a `width`×`height` photo with
/// interleaved RGB `colours`, where the band lies under them; the band samples under
/// soft pixels are given their background's colour source.
pub(super) fn estimate(
    colours: &[f32],
    disparity: &[f32],
    cuts: &Cuts,
    band: &mut Band,
    width: usize,
) -> Mattes {
    let pixels = disparity.len();
    let mut alpha = vec![(f32::INFINITY, 0); pixels];
    for (near, far) in cuts.pairs(disparity) {
        if band.at[near] == NONE {
            continue;
        }
        if let Some(found) = pair_alpha(colours, cuts, near, far, width, pixels) {
            if found.0 < alpha[near].0 {
                alpha[near] = found;
            }
        }
    }
    let mut mattes = Mattes {
        soft: Vec::new(),
        index: vec![NONE; pixels],
    };
    for (p, &(a, outer)) in alpha.iter().enumerate().filter(|(_, &(a, _))| a < OPAQUE) {
        band.source[band.at[p] as usize] = outer as u32;
        mattes.index[p] = mattes.soft.len() as u32;
        mattes.soft.push(Soft {
            sample: p as u32,
            beneath: (pixels + band.at[p] as usize) as u32,
            alpha: a,
        });
    }
    mattes
}

/// The foreground share of `near` from the colours across the cut to `far`, with the
/// pixel outwards that gave the background's colour; None where the object is one pixel
/// thin there, or the two sides hardly differ.
fn pair_alpha(
    colours: &[f32],
    cuts: &Cuts,
    near: usize,
    far: usize,
    width: usize,
    pixels: usize,
) -> Option<(f32, usize)> {
    let inner = step(near, far, width, pixels)?;
    if cuts.between(near, inner) {
        return None;
    }
    let outer = step(far, near, width, pixels)
        .filter(|&o| !cuts.between(far, o))
        .unwrap_or(far);
    let colour = |i: usize| [colours[3 * i], colours[3 * i + 1], colours[3 * i + 2]];
    let (fg, bg, p) = (colour(inner), colour(outer), colour(near));
    let axis: [f32; 3] = std::array::from_fn(|c| fg[c] - bg[c]);
    let length2: f32 = axis.iter().map(|a| a * a).sum();
    if length2 < MIN_CONTRAST * MIN_CONTRAST {
        return None;
    }
    let along: f32 = (0..3).map(|c| (p[c] - bg[c]) * axis[c]).sum();
    Some(((along / length2).clamp(0.0, 1.0), outer))
}

/// The pixel one step from `from` away from its 4-neighbour `towards`, if in the photo.
fn step(from: usize, towards: usize, width: usize, pixels: usize) -> Option<usize> {
    let (fx, tx) = (from % width, towards % width);
    if fx != tx {
        // A horizontal pair: the step continues along the row.
        let x = (2 * fx).checked_sub(tx).filter(|&x| x < width)?;
        Some(from - fx + x)
    } else {
        (2 * from).checked_sub(towards).filter(|&i| i < pixels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cuts_between_columns(width: usize, height: usize, x: usize) -> Cuts {
        let mut horizontal = vec![false; width * height];
        for y in 0..height {
            horizontal[y * width + x] = true;
        }
        Cuts {
            width,
            height,
            horizontal,
            vertical: vec![false; width * height],
            contours_kept: 1,
            contours_dropped: 0,
        }
    }

    /// A row of 6 pixels: foreground (near) in columns 0-2, background from 3; the cut
    /// between 2 and 3; the band under columns 0-2.
    fn scene(edge: [f32; 3]) -> (Vec<f32>, Vec<f32>, Cuts, Band) {
        let fg = [0.9, 0.2, 0.1];
        let bg = [0.1, 0.3, 0.8];
        let row = [fg, fg, edge, bg, bg, bg];
        let colours: Vec<f32> = row.iter().flatten().copied().collect();
        let disparity = vec![2.0, 2.0, 2.0, 1.0, 1.0, 1.0];
        let band = Band {
            at: vec![2, 1, 0, NONE, NONE, NONE],
            disparity: vec![1.0; 3],
            source: vec![3, 4, 5],
        };
        (colours, disparity, cuts_between_columns(6, 1, 2), band)
    }

    #[test]
    fn a_mixed_edge_pixel_gets_its_foreground_share() {
        let mix = |a: f32| {
            let (fg, bg) = ([0.9, 0.2, 0.1], [0.1, 0.3, 0.8]);
            std::array::from_fn(|c| a * fg[c] + (1.0 - a) * bg[c])
        };
        for a in [0.1, 0.35, 0.6, 0.9] {
            let (colours, disparity, cuts, mut band) = scene(mix(a));
            let m = estimate(&colours, &disparity, &cuts, &mut band, 6);
            assert_eq!(m.soft.len(), 1, "alpha {a}");
            let soft = m.soft[0];
            assert_eq!(soft.sample, 2);
            // The band sample at pixel 2 is band entry 0, after the 6 front samples.
            assert_eq!(soft.beneath, 6);
            // The band under it now copies the background the alpha was measured
            // against (pixel 4), not the synthesised source (3).
            assert_eq!(band.source[0], 4);
            assert!((soft.alpha - a).abs() < 1e-5, "{} vs {a}", soft.alpha);
            assert!(m.is_soft(2) && !m.is_soft(1) && !m.is_soft(3));
        }
    }

    #[test]
    fn a_pure_edge_pixel_or_a_low_contrast_edge_stays_hard() {
        let (colours, disparity, cuts, mut band) = scene([0.9, 0.2, 0.1]);
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6).is_empty());
        let grey = [0.5, 0.5, 0.5];
        let colours: Vec<f32> = [grey; 6].iter().flatten().copied().collect();
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6).is_empty());
    }

    #[test]
    fn without_a_band_beneath_an_edge_stays_hard() {
        let (colours, disparity, cuts, mut band) = scene([0.5, 0.25, 0.45]);
        band.at[2] = NONE;
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6).is_empty());
    }

    #[test]
    fn steps_stay_in_the_photo() {
        // 3x2: pixel 4 is (1, 1).
        assert_eq!(step(4, 5, 3, 6), Some(3));
        assert_eq!(step(4, 3, 3, 6), Some(5));
        assert_eq!(step(3, 4, 3, 6), None);
        assert_eq!(step(4, 1, 3, 6), None);
        assert_eq!(step(1, 4, 3, 6), None);
    }
}
