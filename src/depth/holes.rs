//! Holes in depth files: pixels where a sensor (RealSense, Kinect, phone LiDAR) or a
//! renderer (a sky) wrote no depth, as 0, NaN or infinity. `--depth-holes` says what to
//! do with them: refuse the file (the default), put them at the farthest depth the file
//! has (skies), or fill them from their neighbours.
//!
//! Filling works in disparity (1/depth for depth files), where a surface's values change
//! linearly across the image, and follows the photo's colours: a hole pixel takes its
//! depth from the neighbours that look like it, so depth does not bleed across a colour
//! edge (a foreground object's depth into the wall behind it). The holes are filled from
//! their border inwards, layer by layer, so that each value comes the shortest way from
//! valid depth; a few smoothing sweeps over the holes then remove the layers' seams.

use crate::depth::DepthKind;
use crate::io::photo::SrgbImage;

/// What to do with holes in a depth file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HolePolicy {
    /// Refuse the file, naming the holes.
    #[default]
    Refuse,
    /// The farthest valid depth (a renderer's sky, a sensor's out-of-range background).
    Far,
    /// Inpainted from the neighbours, following the photo's colour edges.
    Fill,
}

impl crate::io::keyword::Keyword for HolePolicy {
    const ALL: &'static [(Self, &'static str)] = &[
        (Self::Refuse, "refuse"),
        (Self::Far, "far"),
        (Self::Fill, "fill"),
    ];
}

/// The holes of a map and what they are, for messages and run.json.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Holes {
    pub mask: Vec<bool>,
    pub zero: usize,
    pub nan: usize,
    pub infinite: usize,
    /// Index of the first hole, row-major.
    pub first: Option<usize>,
}

impl Holes {
    /// The holes of `values` read as `kind`: NaN and infinities always; 0 in depth files,
    /// where no surface can be (in disparity, 0 is a valid, infinitely far value).
    pub fn find(values: &[f32], kind: DepthKind) -> Self {
        let mut holes = Self {
            mask: vec![false; values.len()],
            ..Self::default()
        };
        for (i, &v) in values.iter().enumerate() {
            let counter = if v.is_nan() {
                &mut holes.nan
            } else if v.is_infinite() {
                &mut holes.infinite
            } else if v == 0.0 && kind == DepthKind::Depth {
                &mut holes.zero
            } else {
                continue;
            };
            *counter += 1;
            holes.mask[i] = true;
            holes.first.get_or_insert(i);
        }
        holes
    }

    pub fn count(&self) -> usize {
        self.zero + self.nan + self.infinite
    }

    pub fn fraction(&self) -> f64 {
        self.count() as f64 / self.mask.len().max(1) as f64
    }

    /// "3 zero, 1 NaN": what the holes are.
    pub fn describe(&self) -> String {
        [
            (self.zero, "zero"),
            (self.nan, "NaN"),
            (self.infinite, "infinite"),
        ]
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, what)| format!("{n} {what}"))
        .collect::<Vec<_>>()
        .join(", ")
    }
}

/// Sets every hole to the farthest valid value: the largest depth, or the smallest
/// disparity. `values` must hold at least one valid value.
pub fn fill_far(values: &mut [f32], holes: &[bool], kind: DepthKind) {
    let valid = values
        .iter()
        .zip(holes)
        .filter(|(_, &h)| !h)
        .map(|(&v, _)| v);
    let far = match kind {
        DepthKind::Depth => valid.fold(f32::NEG_INFINITY, f32::max),
        DepthKind::Disparity => valid.fold(f32::INFINITY, f32::min),
    };
    for (v, _) in values.iter_mut().zip(holes).filter(|(_, &h)| h) {
        *v = far;
    }
}

/// Fills every hole of the `width`×`height` map `values` (read as `kind`) from the valid
/// values around it, guided by `guide`, the photo at the map's size. `values` must hold
/// at least one valid value. Filled values stay within the valid values' range.
pub fn fill_guided(
    values: &mut [f32],
    holes: &[bool],
    width: usize,
    height: usize,
    kind: DepthKind,
    guide: &SrgbImage,
) {
    assert_eq!(
        (guide.width() as usize, guide.height() as usize),
        (width, height),
        "the guide is the map's size"
    );
    let grid = Grid {
        width,
        height,
        look: guide
            .data()
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
    };
    // To disparity and back: either way the map is its own inverse.
    let disparity_of: fn(f32) -> f32 = match kind {
        DepthKind::Depth => |d| 1.0 / d,
        DepthKind::Disparity => |d| d,
    };
    let mut disparity: Vec<f32> = values
        .iter()
        .zip(holes)
        .map(|(&v, &h)| if h { 0.0 } else { disparity_of(v) })
        .collect();
    let (lo, hi) = disparity
        .iter()
        .zip(holes)
        .filter(|(_, &h)| !h)
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), (&v, _)| {
            (lo.min(v), hi.max(v))
        });
    let order = grid.peel(&mut disparity, holes);
    grid.smooth(&mut disparity, &order);
    for &i in &order {
        // Rounding in the averages must not step outside the valid range.
        values[i] = disparity_of(disparity[i].clamp(lo, hi));
    }
}

/// Colour differences (sRGB, 0..1) at which a neighbour's weight falls to e^-1/2: about
/// the spread of a textured surface's colours, well below the step at an object's edge.
const COLOUR_SIGMA: f32 = 0.1;
/// Smoothing sweeps over the holes after peeling.
const SWEEPS: usize = 4;

/// How much a value seen with colour `b` counts for a pixel of colour `a`. Never quite
/// zero, so that a hole with no look-alike around it still takes its nearest values.
fn likeness(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d2: f32 = (0..3).map(|c| (a[c] - b[c]).powi(2)).sum();
    (-d2 / (2.0 * COLOUR_SIGMA * COLOUR_SIGMA)).exp() + 1e-6
}

/// The map's pixel grid and each pixel's colour.
struct Grid {
    width: usize,
    height: usize,
    look: Vec<[f32; 3]>,
}

impl Grid {
    /// The 8-neighbours of pixel `i`, with weight 1 along the axes and 1/2 diagonally
    /// (a symmetric stencil: it reproduces a plane's values exactly).
    fn neighbours(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let (x, y) = ((i % self.width) as isize, (i / self.width) as isize);
        let (w, h) = (self.width as isize, self.height as isize);
        (-1..=1isize)
            .flat_map(move |dy| (-1..=1isize).map(move |dx| (dx, dy)))
            .filter(move |&(dx, dy)| {
                (dx, dy) != (0, 0) && (0..w).contains(&(x + dx)) && (0..h).contains(&(y + dy))
            })
            .map(move |(dx, dy)| {
                let axis = if dx == 0 || dy == 0 { 1.0 } else { 0.5 };
                (((y + dy) * w + x + dx) as usize, axis)
            })
    }

    /// The mean of `value` over the neighbours of `i` that `use_it` admits, each
    /// weighted by its stencil weight and colour likeness.
    fn mean(&self, value: &[f32], i: usize, use_it: impl Fn(usize) -> bool) -> f32 {
        let (mut sum, mut weight) = (0.0f32, 0.0f32);
        for (n, axis) in self.neighbours(i).filter(|&(n, _)| use_it(n)) {
            let w = axis * likeness(self.look[i], self.look[n]);
            sum += w * value[n];
            weight += w;
        }
        sum / weight
    }

    /// Fills the holes layer by layer from the valid pixels inwards (breadth first over
    /// 8-neighbours): each hole pixel takes the colour-weighted mean of its neighbours in
    /// earlier layers, so values travel the shortest way in, from the surface that looks
    /// like the pixel. Returns the holes in the order they were filled.
    fn peel(&self, value: &mut [f32], holes: &[bool]) -> Vec<usize> {
        let mut layer: Vec<u32> = holes
            .iter()
            .map(|&h| if h { u32::MAX } else { 0 })
            .collect();
        let mut queue: std::collections::VecDeque<usize> =
            (0..holes.len()).filter(|&i| !holes[i]).collect();
        let mut order = Vec::new();
        while let Some(i) = queue.pop_front() {
            for (n, _) in self.neighbours(i) {
                if layer[n] == u32::MAX {
                    layer[n] = layer[i] + 1;
                    queue.push_back(n);
                    order.push(n);
                }
            }
        }
        for &i in &order {
            value[i] = self.mean(value, i, |n| layer[n] < layer[i]);
        }
        order
    }

    /// Gauss-Seidel sweeps over the `holes`, each becoming the colour-weighted mean of
    /// all its neighbours, alternating the scan direction: the layers' seams smooth out
    /// into a continuation of the hole's border.
    fn smooth(&self, value: &mut [f32], holes: &[usize]) {
        for sweep in 0..SWEEPS {
            for k in 0..holes.len() {
                let i = holes[if sweep % 2 == 0 {
                    k
                } else {
                    holes.len() - 1 - k
                }];
                value[i] = self.mean(value, i, |_| true);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_guide(w: usize, h: usize) -> SrgbImage {
        let mut g = SrgbImage::new(w as u32, h as u32);
        for y in 0..h as u32 {
            for x in 0..w as u32 {
                g.put(x, y, [0.5, 0.5, 0.5]);
            }
        }
        g
    }

    #[test]
    fn holes_are_zero_nan_and_infinity_in_depth_and_not_zero_in_disparity() {
        let values = [1.0, 0.0, f32::NAN, f32::INFINITY, -1.0, 0.0];
        let holes = Holes::find(&values, DepthKind::Depth);
        assert_eq!((holes.zero, holes.nan, holes.infinite), (2, 1, 1));
        assert_eq!(holes.first, Some(1));
        assert_eq!(holes.describe(), "2 zero, 1 NaN, 1 infinite");
        assert!((holes.fraction() - 4.0 / 6.0).abs() < 1e-12);
        let holes = Holes::find(&values, DepthKind::Disparity);
        assert_eq!(holes.count(), 2);
        assert!(!holes.mask[1]);
    }

    #[test]
    fn far_is_the_largest_depth_or_the_smallest_disparity() {
        let mut depth = [2.0, 0.0, 5.0, 3.0];
        let holes = Holes::find(&depth, DepthKind::Depth).mask;
        fill_far(&mut depth, &holes, DepthKind::Depth);
        assert_eq!(depth, [2.0, 5.0, 5.0, 3.0]);
        let mut disparity = [0.2, f32::NAN, 0.9, 0.5];
        let holes = Holes::find(&disparity, DepthKind::Disparity).mask;
        fill_far(&mut disparity, &holes, DepthKind::Disparity);
        assert_eq!(disparity, [0.2, 0.2, 0.9, 0.5]);
    }

    #[test]
    fn a_single_hole_in_a_plane_is_filled_exactly() {
        // Disparity linear in x and y: a plane.
        let (w, h) = (9, 7);
        let truth: Vec<f32> = (0..w * h)
            .map(|i| 1.0 / (0.2 + 0.01 * (i % w) as f32 + 0.02 * (i / w) as f32))
            .collect();
        let mut values = truth.clone();
        let centre = 3 * w + 4;
        values[centre] = 0.0;
        let holes = Holes::find(&values, DepthKind::Depth).mask;
        fill_guided(
            &mut values,
            &holes,
            w,
            h,
            DepthKind::Depth,
            &flat_guide(w, h),
        );
        assert!((values[centre] / truth[centre] - 1.0).abs() < 1e-5);
    }

    #[test]
    fn depth_does_not_bleed_across_a_colour_edge() {
        // Left half red at depth 1, right half blue at depth 3; a hole band over the edge.
        let (w, h) = (32, 24);
        let mut guide = SrgbImage::new(w as u32, h as u32);
        let mut values = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let left = x < w / 2;
                guide.put(
                    x as u32,
                    y as u32,
                    if left {
                        [0.9, 0.1, 0.1]
                    } else {
                        [0.1, 0.1, 0.9]
                    },
                );
                let hole = (w / 2 - 6..w / 2 + 6).contains(&x) && (4..h - 4).contains(&y);
                values[y * w + x] = match (hole, left) {
                    (true, _) => f32::NAN,
                    (false, true) => 1.0,
                    (false, false) => 3.0,
                };
            }
        }
        let holes = Holes::find(&values, DepthKind::Depth).mask;
        fill_guided(&mut values, &holes, w, h, DepthKind::Depth, &guide);
        for y in 0..h {
            for x in 0..w {
                let want = if x < w / 2 { 1.0 } else { 3.0 };
                let got = values[y * w + x];
                assert!((got - want).abs() < 0.01 * want, "x={x} y={y}: {got}");
            }
        }
    }

    #[test]
    fn a_map_with_one_valid_value_fills_everything_with_it() {
        let mut values = vec![f32::NAN; 5 * 3];
        values[7] = 2.5;
        let holes = Holes::find(&values, DepthKind::Depth).mask;
        fill_guided(
            &mut values,
            &holes,
            5,
            3,
            DepthKind::Depth,
            &flat_guide(5, 3),
        );
        assert!(values.iter().all(|&v| (v - 2.5).abs() < 1e-6), "{values:?}");
    }
}
