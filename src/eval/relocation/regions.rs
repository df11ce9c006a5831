//! The regions of a novel view where relocation fails first, taken from the true
//! geometry so that every method and every depth source is scored on the same pixels:
//!
//! - **edge**: pixels within [`EDGE_BAND_PX`] of where a depth step of the true depth
//!   lands in the view (both of its sides), where halos, fringes and jagged outlines show;
//! - **uncovered**: pixels the input does not see because an occluder hid them (the
//!   true-depth LDI renders them entirely from its background band);
//! - **border**: pixels beyond the input's frame (nothing of the true-depth LDI covers
//!   them when its border is not extended).

use crate::depth::DepthMap;
use crate::views::Intrinsics;

/// Half-width of the edge band, in view pixels: network depth edges wander a few pixels
/// off the true ones, and the fringes they cause are about as wide.
pub const EDGE_BAND_PX: usize = 3;

/// A neighbour step of the true depth counts as an edge above this fraction of the
/// larger disparity (the LDI cuts at 4 %; the renderer's depth has no ramps to confuse).
const EDGE_STEP: f32 = 0.05;

/// Per view pixel, whether it belongs to each region.
pub struct Regions {
    pub edge: Vec<bool>,
    pub uncovered: Vec<bool>,
    pub border: Vec<bool>,
}

impl Regions {
    /// `front` and `hole` are the per-pixel fractions of a render of the true-depth LDI,
    /// border not extended, that show original pixels and that nothing covered.
    pub fn of_truth(
        depth: &DepthMap,
        source: &Intrinsics,
        offset: [f64; 3],
        front: &[f32],
        hole: &[f32],
    ) -> Self {
        let (w, h) = (depth.width(), depth.height());
        let mut landed = vec![false; w * h];
        for (a, b) in steps(depth) {
            for i in [a, b] {
                if let Some(j) = project(depth, source, offset, i) {
                    landed[j] = true;
                }
            }
        }
        Self {
            edge: dilate(&landed, w, h, EDGE_BAND_PX),
            uncovered: front
                .iter()
                .zip(hole)
                .map(|(&f, &o)| f == 0.0 && o == 0.0)
                .collect(),
            border: hole.iter().map(|&o| o == 1.0).collect(),
        }
    }
}

/// Pairs of 4-neighbours whose disparities differ by more than [`EDGE_STEP`].
fn steps(depth: &DepthMap) -> Vec<(usize, usize)> {
    let (w, h) = (depth.width(), depth.height());
    let d: Vec<f32> = depth.data().iter().map(|&z| 1.0 / z).collect();
    let step = |a: usize, b: usize| (d[a] - d[b]).abs() > EDGE_STEP * d[a].max(d[b]);
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if x + 1 < w && step(i, i + 1) {
                out.push((i, i + 1));
            }
            if y + 1 < h && step(i, i + w) {
                out.push((i, i + w));
            }
        }
    }
    out
}

/// The view pixel where the centre of input pixel `i` lands, if inside the view.
fn project(depth: &DepthMap, k: &Intrinsics, t: [f64; 3], i: usize) -> Option<usize> {
    let w = depth.width();
    let (u, v) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
    let z = f64::from(depth.data()[i]);
    let p = [
        (u - k.cx) / k.fx * z - t[0],
        (v - k.cy) / k.fy * z - t[1],
        z - t[2],
    ];
    if p[2] <= 1e-9 {
        return None;
    }
    let (x, y) = (k.fx * p[0] / p[2] + k.cx, k.fy * p[1] / p[2] + k.cy);
    let inside = x >= 0.0 && y >= 0.0 && x < w as f64 && y < depth.height() as f64;
    inside.then(|| y as usize * w + x as usize)
}

/// `mask` grown by `r` pixels in every direction (a square neighbourhood).
fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            rows[y * w + x] = (x.saturating_sub(r)..(x + r + 1).min(w)).any(|s| mask[y * w + s]);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (y.saturating_sub(r)..(y + r + 1).min(h)).any(|s| rows[s * w + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(w: u32, h: u32) -> Intrinsics {
        Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: f64::from(w) / 2.0,
            cy: f64::from(h) / 2.0,
            width: w,
            height: h,
        }
    }

    #[test]
    fn the_edge_band_follows_the_step_into_the_view() {
        // A near half (depth 1) left of a far half (depth 4): a view 0.1 to the right
        // sees the near side of the step at x = 21 (10 px left) and the far side at
        // x = 30 (2.5 px left); between them the view uncovers background.
        let (w, h) = (64, 8);
        let depth = DepthMap::new(
            w,
            h,
            (0..w * h)
                .map(|i| if i % w < 32 { 1.0 } else { 4.0 })
                .collect(),
        );
        let none = vec![1.0; w * h];
        let zero = vec![0.0; w * h];
        let r = Regions::of_truth(&depth, &camera(64, 8), [0.1, 0.0, 0.0], &none, &zero);
        let row: Vec<bool> = r.edge[3 * w..4 * w].to_vec();
        for x in [18, 21, 24, 27, 30, 33] {
            assert!(row[x], "x = {x} should be in the band");
        }
        for x in [10, 17, 25, 26, 34, 40] {
            assert!(!row[x], "x = {x} should not be in the band");
        }
    }

    #[test]
    fn uncovered_and_border_come_from_the_render_fractions() {
        let depth = DepthMap::new(3, 1, vec![1.0; 3]);
        let r = Regions::of_truth(
            &depth,
            &camera(3, 1),
            [0.0; 3],
            &[0.0, 0.0, 1.0],
            &[1.0, 0.0, 0.0],
        );
        assert_eq!(r.uncovered, vec![false, true, false]);
        assert_eq!(r.border, vec![true, false, false]);
        assert!(r.edge.iter().all(|&e| !e));
    }
}
