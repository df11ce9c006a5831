//! Soft silhouettes. A photo's edges spread over a pixel or so: the pixels either side
//! of a silhouette mix the object and the background behind it. Cut by depth alone, a
//! near-side pixel moves with the object and carries its share of the old background
//! along (a rim of the wrong colour wherever a view sees the object against another
//! background), and a far-side pixel stays on the background with its share of the
//! object (a faint copy of the outline left behind when the object moves).
//!
//! Each such pixel gets its foreground share α, its colour's position between the
//! object's colour one pixel inwards and the background's one or two pixels outwards.
//! A near-side pixel is drawn after the opaque ones, over whatever lies behind it in the
//! view, exchanging its background share: `p + (1 − α)·(behind − beneath)`, where
//! `beneath` is the band sample under it. That band sample takes its colour from the
//! background pixel the share was measured against (instead of the one patch synthesis
//! chose), so that what is taken out is the background the share assumed, not a
//! texture copied from elsewhere that would speckle the edge. A far-side pixel takes
//! that background pixel's colour itself, and a quad of its own on the object's surface
//! carries its share with the object, drawn the same way with the pixel as `beneath`.
//! At the photo's camera what lies behind a soft pixel is what was beneath it, so the
//! photo is reproduced exactly.

use super::band::{Band, NONE};
use super::edges::Cuts;
use super::mesh::{Mesh, Sample, Vertex};

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

/// The soft pixels of an LDI, and which samples they are.
#[derive(Default)]
pub(super) struct Mattes {
    pub soft: Vec<Soft>,
    /// Per sample: whether it is one of `soft` (samples past the end are not).
    pub in_soft_pass: Vec<bool>,
}

impl Mattes {
    pub fn is_empty(&self) -> bool {
        self.soft.is_empty()
    }

    pub fn heap_bytes(&self) -> usize {
        self.soft.capacity() * std::mem::size_of::<Soft>() + self.in_soft_pass.capacity()
    }

    /// Whether sample `s` is drawn in the soft pass rather than with the opaque ones.
    pub fn is_soft(&self, s: u32) -> bool {
        self.in_soft_pass.get(s as usize).copied().unwrap_or(false)
    }
}

/// The alphas of the pixels on either side of every cut of a `width`×`height` photo
/// with interleaved RGB `colours`: near-side pixels where the band lies under them, and
/// the far-side pixels that hold a share of the foreground ([`Fringe`], drawn once the
/// mesh is built: [`add_fringes`]). The band samples under near-side soft pixels are
/// given their background's colour source.
pub(super) fn estimate(
    colours: &[f32],
    disparity: &[f32],
    cuts: &Cuts,
    band: &mut Band,
    width: usize,
) -> (Mattes, Vec<Fringe>) {
    let pixels = disparity.len();
    let mut alpha = vec![(f32::INFINITY, 0); pixels];
    let mut fringe: Vec<Option<Fringe>> = vec![None; pixels];
    let mut is_near = vec![false; pixels];
    for (near, far) in cuts.pairs(disparity) {
        is_near[near] = true;
        if band.at[near] == NONE {
            continue;
        }
        let Some(shares) = pair_shares(colours, cuts, near, far, width, pixels) else {
            continue;
        };
        if shares.near < alpha[near].0 {
            alpha[near] = (shares.near, shares.outer);
        }
        if shares.far >= FRINGE && fringe[far].is_none_or(|f| shares.far > f.alpha) {
            fringe[far] = Some(Fringe {
                pixel: far,
                near,
                outer: shares.outer,
                alpha: shares.far,
            });
        }
    }
    let mut mattes = Mattes {
        soft: Vec::new(),
        in_soft_pass: vec![false; pixels],
    };
    for (p, &(a, outer)) in alpha.iter().enumerate().filter(|(_, &(a, _))| a < OPAQUE) {
        band.source[band.at[p] as usize] = outer as u32;
        mattes.in_soft_pass[p] = true;
        mattes.soft.push(Soft {
            sample: p as u32,
            beneath: (pixels + band.at[p] as usize) as u32,
            alpha: a,
        });
    }
    let height = pixels / width;
    let inside =
        |p: usize| (1..width - 1).contains(&(p % width)) && (1..height - 1).contains(&(p / width));
    let fringes = fringe
        .into_iter()
        .flatten()
        .filter(|f| !is_near[f.pixel] && inside(f.pixel))
        .collect();
    (mattes, fringes)
}

/// Far-side shares below this stay with the background: a trace of the foreground's
/// colour under a level.
const FRINGE: f32 = 0.05;

/// A background pixel beside a cut that holds a share of the foreground: the photo's
/// edge spread across the cut. Left in the background, that share would stay behind as
/// a faint copy of the outline when the foreground moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Fringe {
    pub pixel: usize,
    /// The foreground pixel across the cut, whose surface the share moves with.
    pub near: usize,
    /// The background pixel the share was measured against.
    pub outer: usize,
    pub alpha: f32,
}

/// Gives each fringe pixel a quad of its own on the foreground's surface, continuing
/// its near pixel's quad across the cut (sharing that quad's two corners on the cut),
/// drawn as a soft pixel with the fringe's share; the background pixel itself then
/// takes the colour of the background the share was measured against, so that what the
/// photo's camera sees is unchanged and what moves with the foreground is its share.
/// `ray` gives a pixel corner's ray.
pub(super) fn add_fringes(
    mesh: &mut Mesh,
    mattes: &mut Mattes,
    fringes: &[Fringe],
    width: usize,
    ray: &dyn Fn(f64, f64) -> [f32; 2],
) {
    mesh.vertices.reserve_exact(2 * fringes.len());
    mesh.samples.reserve_exact(fringes.len());
    mattes.in_soft_pass.resize(mesh.samples.len(), false);
    for f in fringes {
        let corners = mesh.samples[f.near].corners;
        // Per fringe corner (top-left, top-right, bottom-left, bottom-right): the near
        // quad's corner it shares (on the cut) or continues (across the fringe), and
        // which of the two.
        let plan: [(usize, bool); 4] = match f.pixel {
            p if p == f.near + 1 => [(1, true), (1, false), (3, true), (3, false)],
            p if p + 1 == f.near => [(0, false), (0, true), (2, false), (2, true)],
            p if p == f.near + width => [(2, true), (3, true), (2, false), (3, false)],
            _ => [(0, false), (1, false), (0, true), (1, true)],
        };
        let (x, y) = ((f.pixel % width) as f64, (f.pixel / width) as f64);
        let mut quad = [0u32; 4];
        for (fc, &(nc, shared)) in plan.iter().enumerate() {
            quad[fc] = if shared {
                corners[nc]
            } else {
                let (u, v) = (x + (fc % 2) as f64, y + (fc / 2) as f64);
                mesh.vertices.push(Vertex {
                    ray: ray(u, v),
                    disparity: mesh.vertices[corners[nc] as usize].disparity,
                });
                mesh.vertices.len() as u32 - 1
            };
        }
        let sample = mesh.samples.len() as u32;
        mesh.samples.push(Sample {
            corners: quad,
            colour_from: f.pixel as u32,
        });
        mesh.samples[f.pixel].colour_from = f.outer as u32;
        mattes.soft.push(Soft {
            sample,
            beneath: f.pixel as u32,
            alpha: f.alpha,
        });
        mattes.in_soft_pass.push(true);
    }
}

/// The foreground shares of the two pixels of a cut, from their colours' positions
/// between the foreground (a pixel inwards) and the background (a pixel outwards).
struct Shares {
    near: f32,
    far: f32,
    /// The pixel outwards that gave the background's colour.
    outer: usize,
}

/// The shares of `near` and `far`; None where the object is one pixel thin there, or
/// the two sides hardly differ. The far pixel has no share where nothing lies beyond it
/// to measure the background by.
fn pair_shares(
    colours: &[f32],
    cuts: &Cuts,
    near: usize,
    far: usize,
    width: usize,
    pixels: usize,
) -> Option<Shares> {
    let inner = step(near, far, width, pixels)?;
    if cuts.between(near, inner) {
        return None;
    }
    let outer = step(far, near, width, pixels)
        .filter(|&o| !cuts.between(far, o))
        .unwrap_or(far);
    let colour = |i: usize| [colours[3 * i], colours[3 * i + 1], colours[3 * i + 2]];
    let (fg, bg) = (colour(inner), colour(outer));
    let axis: [f32; 3] = std::array::from_fn(|c| fg[c] - bg[c]);
    let length2: f32 = axis.iter().map(|a| a * a).sum();
    if length2 < MIN_CONTRAST * MIN_CONTRAST {
        return None;
    }
    let share = |p: [f32; 3]| {
        let along: f32 = (0..3).map(|c| (p[c] - bg[c]) * axis[c]).sum();
        (along / length2).clamp(0.0, 1.0)
    };
    Some(Shares {
        near: share(colour(near)),
        far: if outer == far {
            0.0
        } else {
            share(colour(far))
        },
        outer,
    })
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
            let (m, fringes) = estimate(&colours, &disparity, &cuts, &mut band, 6);
            assert!(fringes.is_empty());
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
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6)
            .0
            .is_empty());
        let grey = [0.5, 0.5, 0.5];
        let colours: Vec<f32> = [grey; 6].iter().flatten().copied().collect();
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6)
            .0
            .is_empty());
    }

    #[test]
    fn without_a_band_beneath_an_edge_stays_hard() {
        let (colours, disparity, cuts, mut band) = scene([0.5, 0.25, 0.45]);
        band.at[2] = NONE;
        assert!(estimate(&colours, &disparity, &cuts, &mut band, 6)
            .0
            .is_empty());
    }

    #[test]
    fn a_background_pixel_holding_part_of_the_foreground_is_a_fringe() {
        // Rows of seven pixels: the foreground in 0-2, the background from 3, pixel 3
        // mixed; the band under 0-2 of every row.
        let (fg, bg) = ([0.9, 0.2, 0.1], [0.1, 0.3, 0.8]);
        let mixed: [f32; 3] = std::array::from_fn(|c| 0.3 * fg[c] + 0.7 * bg[c]);
        let fringes_of = |rows: usize| {
            let row = [fg, fg, fg, mixed, bg, bg, bg];
            let colours: Vec<f32> = row
                .iter()
                .flatten()
                .copied()
                .collect::<Vec<_>>()
                .repeat(rows);
            let disparity = [2.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0].repeat(rows);
            let at = (0..rows as u32)
                .flat_map(|r| [3 * r + 2, 3 * r + 1, 3 * r, NONE, NONE, NONE, NONE])
                .collect();
            let mut band = Band {
                at,
                disparity: vec![1.0; 3 * rows],
                source: vec![4; 3 * rows],
            };
            let cuts = cuts_between_columns(7, rows, 2);
            let (m, fringes) = estimate(&colours, &disparity, &cuts, &mut band, 7);
            assert!(m.is_empty(), "the near pixels are pure foreground");
            fringes
        };
        assert!(
            fringes_of(1).is_empty(),
            "a one-row photo has no pixel inside its border"
        );
        let fringes = fringes_of(3);
        assert_eq!(fringes.len(), 1, "only the middle row is inside the border");
        let f = fringes[0];
        assert_eq!((f.pixel, f.near, f.outer), (10, 9, 11));
        assert!((f.alpha - 0.3).abs() < 1e-5, "{}", f.alpha);
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
