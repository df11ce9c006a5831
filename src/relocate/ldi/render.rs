//! Rendering the layered mesh from one view: project the corners, rasterise every
//! sample's quad into a supersampled id/depth buffer (nearest wins), fill what no quad
//! covers from the farthest surface next to it, then resolve colours and average the
//! subsamples, which anti-aliases the silhouettes.

use super::mesh::{Mesh, Vertex};
use crate::relocate::raster_triangle;
use crate::views::Intrinsics;

/// Where a subsample's colour came from.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Origin {
    Front,
    Back,
    Filled,
}

/// A rendered, not yet resolved view at `factor`× the output resolution.
pub(super) struct Frame {
    pub width: usize,
    pub height: usize,
    pub factor: usize,
    pub sample: Vec<u32>,
    pub origin: Vec<Origin>,
    /// 1/z per subsample; filled subsamples have the surface they were filled from.
    pub inv_z: Vec<f32>,
}

/// No sample: a subsample that nothing covered, not even after hole filling (a view
/// that sees none of the mesh).
pub(super) const EMPTY: u32 = u32::MAX;

/// Projects and rasterises `mesh` for a camera at `centre` (in the build camera's frame)
/// with intrinsics `k` (already supersampled). `front_samples` is how many samples are
/// original pixels.
pub(super) fn rasterise(
    mesh: &Mesh,
    front_samples: usize,
    centre: [f64; 3],
    k: &Intrinsics,
    factor: usize,
) -> Frame {
    let (w, h) = (k.width as usize, k.height as usize);
    let projected = project(mesh, centre, k);
    let mut inv_z = vec![0.0f32; w * h];
    let mut sample = vec![EMPTY; w * h];
    for (s, quad) in mesh.samples.iter().enumerate() {
        let [a, b, c, d] = quad.corners.map(|i| projected[i as usize]);
        if outside([a, b, c, d], w as f32, h as f32) {
            continue;
        }
        for tri in [[a, b, c], [b, d, c]] {
            fill_triangle(tri, s as u32, w, h, &mut inv_z, &mut sample);
        }
    }
    let origin = sample
        .iter()
        .map(|&s| match s {
            EMPTY => Origin::Filled,
            s if (s as usize) < front_samples => Origin::Front,
            _ => Origin::Back,
        })
        .collect();
    fill_holes(&mut sample, &mut inv_z, w, h);
    Frame {
        width: w,
        height: h,
        factor,
        sample,
        origin,
        inv_z,
    }
}

/// Whether a quad lies wholly beyond one side of the `w`x`h` frame, with a pixel's
/// margin: the photo fitted to cover a view is often wider (or taller) than it, and
/// such quads cost a triangle setup each for nothing.
fn outside(q: [[f32; 3]; 4], w: f32, h: f32) -> bool {
    q.iter().all(|p| p[0] < -1.0)
        || q.iter().all(|p| p[0] > w + 1.0)
        || q.iter().all(|p| p[1] < -1.0)
        || q.iter().all(|p| p[1] > h + 1.0)
}

/// Screen position and 1/z of every vertex; 1/z = 0 marks a vertex behind the camera
/// or one whose position is not a finite number (a camera absurdly far away), which no
/// triangle then uses. `centre` is in the mesh's units (see [`super::Ldi`]'s scale).
fn project(mesh: &Mesh, centre: [f64; 3], k: &Intrinsics) -> Vec<[f32; 3]> {
    mesh.vertices
        .iter()
        .map(|v| project_vertex(v, centre, k).unwrap_or([0.0; 3]))
        .collect()
}

/// A vertex's pixel position and 1/z in the camera at `centre` with intrinsics `k`;
/// None behind the camera or where the numbers overflow.
pub(super) fn project_vertex(v: &Vertex, centre: [f64; 3], k: &Intrinsics) -> Option<[f32; 3]> {
    let [tx, ty, tz] = centre.map(|c| c as f32);
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let z = 1.0 / v.disparity;
    let (qx, qy, qz) = (v.ray[0] * z - tx, v.ray[1] * z - ty, z - tz);
    // NaN comes from an infinite camera offset.
    if qz.is_nan() || qz <= 1e-6 {
        return None;
    }
    let inv = 1.0 / qz;
    let p = [fx * qx * inv + cx, fy * qy * inv + cy, inv];
    (p.iter().all(|c| c.is_finite()) && inv > 0.0).then_some(p)
}

/// Writes `id` into the pixel centres inside the triangle where it is nearer than what
/// is there; 1/z is affine on screen.
fn fill_triangle(
    p: [[f32; 3]; 3],
    id: u32,
    w: usize,
    h: usize,
    inv_z: &mut [f32],
    sample: &mut [u32],
) {
    if p.iter().any(|v| v[2] <= 0.0) {
        return;
    }
    let corners = p.map(|v| [f64::from(v[0]), f64::from(v[1])]);
    raster_triangle(corners, w, h, |i, b| {
        let z = b[0] as f32 * p[0][2] + b[1] as f32 * p[1][2] + b[2] as f32 * p[2][2];
        if z > inv_z[i] {
            inv_z[i] = z;
            sample[i] = id;
        }
    });
}

/// Each uncovered subsample takes the sample of the farthest of the nearest covered
/// subsamples to its left, right, top and bottom: what is left uncovered opens next to
/// an occluder or the frame, and the background lies on the far side. A subsample
/// whose whole row and column are uncovered (a view that sees the mesh in one corner
/// only) is filled by a second pass from the first one's results; one that sees
/// nothing at all stays [`EMPTY`].
fn fill_holes(sample: &mut [u32], inv_z: &mut [f32], w: usize, h: usize) {
    for _ in 0..2 {
        if !sample.contains(&EMPTY) || sample.iter().all(|&s| s == EMPTY) {
            return;
        }
        fill_pass(sample, inv_z, w, h);
    }
}

fn fill_pass(sample: &mut [u32], inv_z: &mut [f32], w: usize, h: usize) {
    // The covered subsample each uncovered one takes, or NONE: u32 indices keep this
    // scratch a quarter of Option<usize>'s size (a view has far fewer subsamples).
    const NONE: u32 = u32::MAX;
    let mut best = vec![NONE; w * h];
    // (first index, stride, length) of every row and column.
    let rows = (0..h).map(|y| (y * w, 1, w));
    let columns = (0..w).map(|x| (x, w, h));
    for (start, stride, len) in rows.chain(columns) {
        for reversed in [false, true] {
            let mut last = NONE;
            for k in 0..len {
                let i = start + stride * if reversed { len - 1 - k } else { k };
                if sample[i] != EMPTY {
                    last = i as u32;
                } else if last != NONE {
                    let b = best[i];
                    if b == NONE || inv_z[last as usize] < inv_z[b as usize] {
                        best[i] = last;
                    }
                }
            }
        }
    }
    for (i, &b) in best.iter().enumerate() {
        if sample[i] == EMPTY && b != NONE {
            sample[i] = sample[b as usize];
            inv_z[i] = inv_z[b as usize];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::outside;

    #[test]
    fn only_quads_wholly_beyond_one_side_are_culled() {
        let quad = |x: f32, y: f32| {
            [
                [x, y, 1.0],
                [x + 2.0, y, 1.0],
                [x, y + 2.0, 1.0],
                [x + 2.0, y + 2.0, 1.0],
            ]
        };
        let (w, h) = (100.0, 50.0);
        for beyond in [
            quad(-4.0, 10.0),
            quad(102.0, 10.0),
            quad(10.0, -4.0),
            quad(10.0, 52.0),
        ] {
            assert!(outside(beyond, w, h), "{beyond:?}");
        }
        // Straddling an edge, within the margin, or inside: rasterised.
        for kept in [
            quad(-1.5, 10.0),
            quad(-2.5, 10.0),
            quad(99.5, 49.5),
            quad(10.0, 10.0),
        ] {
            assert!(!outside(kept, w, h), "{kept:?}");
        }
    }
}
