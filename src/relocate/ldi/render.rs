//! Rendering the layered mesh from one view: project the corners, rasterise every
//! opaque sample's quad into a supersampled id/depth buffer (nearest wins), list where
//! the soft pixels of the silhouettes lie in front of it, fill what no quad covers from
//! the farthest surface next to it, then resolve colours (blending the soft pixels over
//! what is behind them) and average the subsamples, which anti-aliases the silhouettes.

use super::matte::Mattes;
use super::mesh::{Mesh, Vertex};
use crate::relocate::{first_centre, past_last_centre, raster_triangle};
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
    /// Where each subsample's colour came from, when asked for.
    pub origin: Option<Vec<Origin>>,
    /// 1/z per subsample; filled subsamples have the surface they were filled from.
    pub inv_z: Vec<f32>,
    /// The subsamples a soft pixel lies in front of, in index order, each with the
    /// pixel's index among the [`Mattes`]: `sample` still holds what lies behind it.
    pub overlay: Vec<(u32, u32)>,
}

/// No sample: a subsample that nothing covered, not even after hole filling (a view
/// that sees none of the mesh).
pub(super) const EMPTY: u32 = u32::MAX;

/// Projects and rasterises `mesh` for a camera at `centre` (in the build camera's frame)
/// with intrinsics `k` (already supersampled). `front_samples` is how many samples are
/// original pixels. The soft pixels of `mattes` are left out of the opaque pass and laid
/// over its result.
pub(super) fn rasterise(
    mesh: &Mesh,
    mattes: &Mattes,
    front_samples: usize,
    centre: [f64; 3],
    k: &Intrinsics,
    factor: usize,
    origins: bool,
) -> Frame {
    let (w, h) = (k.width as usize, k.height as usize);
    let projected = project(mesh, centre, k);
    let mut inv_z = vec![0.0f32; w * h];
    let mut sample = vec![EMPTY; w * h];
    let mut rows = Scanlines::default();
    for (s, quad) in mesh.samples.iter().enumerate() {
        let s = s as u32;
        let [a, b, c, d] = quad.corners.map(|i| projected[i as usize]);
        if outside([a, b, c, d], w as f32, h as f32) || mattes.is_soft(s) {
            continue;
        }
        if !fill_trapezoid([a, b, c, d], s, w, h, &mut rows, &mut inv_z, &mut sample) {
            for tri in [[a, b, c], [b, d, c]] {
                fill_triangle(tri, s, w, h, &mut inv_z, &mut sample);
            }
        }
    }
    let mut origin: Option<Vec<Origin>> = origins.then(|| {
        sample
            .iter()
            .map(|&s| match s {
                EMPTY => Origin::Filled,
                s if (s as usize) < front_samples => Origin::Front,
                _ => Origin::Back,
            })
            .collect()
    });
    // Before the holes are filled: a subsample that only a soft pixel covers is the
    // soft pixel's, over whatever the fill then puts behind it.
    let overlay = overlay(mesh, mattes, &projected, w, h, &inv_z);
    fill_holes(&mut sample, &mut inv_z, w, h);
    if let Some(origin) = &mut origin {
        for &(i, _) in &overlay {
            origin[i as usize] = Origin::Front;
        }
    }
    Frame {
        width: w,
        height: h,
        factor,
        sample,
        origin,
        inv_z,
        overlay,
    }
}

/// The subsamples where a soft pixel is the nearest surface, with the nearest soft
/// pixel there. Soft pixels are a thin line along the silhouettes, so they are drawn as
/// triangles into a list instead of a second frame-sized buffer.
fn overlay(
    mesh: &Mesh,
    mattes: &Mattes,
    projected: &[[f32; 3]],
    w: usize,
    h: usize,
    opaque: &[f32],
) -> Vec<(u32, u32)> {
    let mut hits: Vec<(u32, f32, u32)> = Vec::new();
    for (m, soft) in mattes.soft.iter().enumerate() {
        let quad = mesh.samples[soft.sample as usize]
            .corners
            .map(|i| projected[i as usize]);
        if outside(quad, w as f32, h as f32) {
            continue;
        }
        let [a, b, c, d] = quad;
        for tri in [[a, b, c], [b, d, c]] {
            raster_depth(tri, w, h, |i, z| {
                if z > opaque[i] {
                    hits.push((i as u32, z, m as u32));
                }
            });
        }
    }
    // Nearest first within each subsample, then one per subsample.
    hits.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
    hits.dedup_by_key(|hit| hit.0);
    hits.into_iter().map(|(i, _, m)| (i, m)).collect()
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
    let p = if ty == 0.0 && tz == 0.0 {
        // A camera moved sideways only (every view of a lenticular rig): 1/z is the
        // disparity itself, x shifts by the disparity's parallax and y stays put. No
        // division, and every row of corners stays exactly on one screen row whatever
        // its depths, which lets the quads rasterise as trapezoids.
        if !(v.disparity > 0.0 && v.disparity < 1e6) {
            return None;
        }
        [
            fx * (v.ray[0] - tx * v.disparity) + cx,
            fy * v.ray[1] + cy,
            v.disparity,
        ]
    } else {
        let z = 1.0 / v.disparity;
        let (qx, qy, qz) = (v.ray[0] * z - tx, v.ray[1] * z - ty, z - tz);
        // NaN comes from an infinite camera offset.
        if qz.is_nan() || qz <= 1e-6 {
            return None;
        }
        let inv = 1.0 / qz;
        [fx * qx * inv + cx, fy * qy * inv + cy, inv]
    };
    (p.iter().all(|c| c.is_finite()) && p[2] > 0.0).then_some(p)
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
    raster_depth(p, w, h, |i, z| {
        if z > inv_z[i] {
            inv_z[i] = z;
            sample[i] = id;
        }
    });
}

/// Visits the pixel centres inside the triangle with their 1/z (affine on screen);
/// nothing for a triangle with a corner behind the camera.
fn raster_depth(p: [[f32; 3]; 3], w: usize, h: usize, mut visit: impl FnMut(usize, f32)) {
    if p.iter().any(|v| v[2] <= 0.0) {
        return;
    }
    let corners = p.map(|v| [f64::from(v[0]), f64::from(v[1])]);
    raster_triangle(corners, w, h, |i, b| {
        visit(
            i,
            b[0] as f32 * p[0][2] + b[1] as f32 * p[1][2] + b[2] as f32 * p[2][2],
        );
    });
}

/// Rasterises the quad (corners top-left, top-right, bottom-left, bottom-right) as the
/// two triangles `[a, b, c]` and `[b, d, c]` would be, in one pass of scanlines, when
/// its top and bottom edges are horizontal and it is not folded over: the case of every
/// quad of a sideways camera. False, having drawn nothing, for any other quad.
///
/// A centre on an edge is covered by both quads that share it, as with
/// [`fill_triangle`]: neighbours compute the edge from the same corners, so no crack
/// opens between them; nearer (or, at equal depth, earlier) wins as before.
fn fill_trapezoid(
    q: [[f32; 3]; 4],
    id: u32,
    w: usize,
    h: usize,
    rows: &mut Scanlines,
    inv_z: &mut [f32],
    sample: &mut [u32],
) -> bool {
    let [a, b, c, d] = q.map(|v| v.map(f64::from));
    let proper = a[1] == b[1] && c[1] == d[1] && a[1] < c[1] && a[0] <= b[0] && c[0] <= d[0];
    if !proper || q.iter().any(|v| v[2] <= 0.0) {
        return false;
    }
    // 1/z is affine over each triangle. Along a row it changes as along the triangle's
    // horizontal edge (the top one for [a, b, c], the bottom one for [b, d, c]), and each
    // row starts from the triangle's vertical-ish edge: a-c for the upper, b-d for the
    // lower. A triangle of no width draws nothing, and its neighbour covers the quad.
    let (top_w, bottom_w) = (b[0] - a[0], d[0] - c[0]);
    let upper = (top_w > 0.0).then(|| (b[2] - a[2]) / top_w);
    let lower = (bottom_w > 0.0).then(|| (d[2] - c[2]) / bottom_w);
    if upper.is_none() && lower.is_none() {
        return true;
    }
    let (first_row, fractions) = rows.between(a[1], c[1], h);
    for (y, &t) in (first_row..).zip(fractions) {
        let along = |p: [f64; 3], q: [f64; 3]| [p[0] + t * (q[0] - p[0]), p[2] + t * (q[2] - p[2])];
        let (left, right) = (along(a, c), along(b, d));
        let xs = first_centre(left[0] - 0.5 - EPS, w);
        let xe = past_last_centre(right[0] - 0.5 + EPS, w);
        if xe <= xs {
            continue;
        }
        let split = match (upper, lower) {
            (Some(_), Some(_)) => past_last_centre(along(b, c)[0] - 0.5, w).clamp(xs, xe),
            (Some(_), None) => xe,
            (None, _) => xs,
        };
        let row = y * w;
        let spans = [
            (xs..split, left, upper.unwrap_or(0.0)),
            (split..xe, right, lower.unwrap_or(0.0)),
        ];
        for (span, [x0, z0], gradient) in spans {
            let pixels = row + span.start..row + span.end;
            let (zs, ss) = (&mut inv_z[pixels.clone()], &mut sample[pixels]);
            for (k, (old_z, old_s)) in zs.iter_mut().zip(ss).enumerate() {
                let u = (span.start + k) as f64 + 0.5;
                let z = (z0 + gradient * (u - x0)) as f32;
                // Selects rather than branches: which quad is nearer is unpredictable.
                let nearer = z > *old_z;
                *old_z = if nearer { z } else { *old_z };
                *old_s = if nearer { id } else { *old_s };
            }
        }
    }
    true
}

/// The pixel rows whose centres lie between two screen heights, each with how far down
/// it lies (0 at the top, 1 at the bottom). A sideways camera keeps every row of mesh
/// corners on one screen row, so all the quads of a photo row share their scanlines,
/// and the quads come in row order: worked out once per photo row, not once per quad.
#[derive(Default)]
struct Scanlines {
    top: f64,
    bottom: f64,
    first: usize,
    fractions: Vec<f64>,
}

impl Scanlines {
    fn between(&mut self, top: f64, bottom: f64, h: usize) -> (usize, &[f64]) {
        if (top, bottom) != (self.top, self.bottom) || self.fractions.is_empty() {
            let per_pixel = 1.0 / (bottom - top);
            let rows = first_centre(top - 0.5 - EPS, h)..past_last_centre(bottom - 0.5 + EPS, h);
            self.first = rows.start;
            self.fractions.clear();
            self.fractions
                .extend(rows.map(|y| ((y as f64 + 0.5 - top) * per_pixel).clamp(0.0, 1.0)));
            (self.top, self.bottom) = (top, bottom);
        }
        (self.first, &self.fractions)
    }
}

/// How far past an edge a pixel centre still counts as on it, in pixels: rounding
/// must not open cracks between quads that share the edge.
const EPS: f64 = 1e-6;

/// Each uncovered subsample takes the sample of the farthest of the nearest covered
/// subsamples to its left, right, top and bottom: what is left uncovered opens next to
/// an occluder or the frame, and the background lies on the far side. A subsample
/// whose whole row and column are uncovered (a view that sees the mesh in one corner
/// only) is filled by a second pass from the first one's results; one that sees
/// nothing at all stays [`EMPTY`].
fn fill_holes(sample: &mut [u32], inv_z: &mut [f32], w: usize, h: usize) {
    for _ in 0..2 {
        match few_holes(sample, w * h / SPARSE) {
            Some(holes) if holes.is_empty() => return,
            Some(holes) => fill_sparse(sample, inv_z, w, h, &holes),
            None if sample.iter().all(|&s| s == EMPTY) => return,
            None => fill_pass(sample, inv_z, w, h),
        }
    }
}

/// Holes are looked up one by one while they are at most one subsample in this many;
/// beyond that, sweeping the whole frame is cheaper than walking from each hole.
const SPARSE: usize = 64;

/// The uncovered subsamples, or None when there are more than `limit`.
fn few_holes(sample: &[u32], limit: usize) -> Option<Vec<usize>> {
    let mut holes = Vec::new();
    for (i, _) in sample.iter().enumerate().filter(|&(_, &s)| s == EMPTY) {
        if holes.len() == limit {
            return None;
        }
        holes.push(i);
    }
    Some(holes)
}

/// [`fill_pass`] for a few holes: a view usually leaves a thousandth of its subsamples
/// uncovered, and sweeping every row and column for them took 2 ms a view. Each hole
/// walks to the nearest covered subsample left, right, above and below, and takes the
/// farthest of them, the first at equal depth: what the sweeps offer, in their order.
fn fill_sparse(sample: &mut [u32], inv_z: &mut [f32], w: usize, h: usize, holes: &[usize]) {
    let covered = |i: &usize| sample[*i] != EMPTY;
    let fills: Vec<(usize, Option<usize>)> = holes
        .iter()
        .map(|&i| {
            let (x, y) = (i % w, i / w);
            let row = y * w;
            let left = (row..i).rev().find(covered);
            let right = (i + 1..row + w).find(covered);
            let above = (0..y).rev().map(|k| k * w + x).find(covered);
            let below = (y + 1..h).map(|k| k * w + x).find(covered);
            let farthest =
                [left, right, above, below]
                    .into_iter()
                    .flatten()
                    .reduce(|best, from| {
                        if inv_z[from] < inv_z[best] {
                            from
                        } else {
                            best
                        }
                    });
            (i, farthest)
        })
        .collect();
    for (i, from) in fills {
        if let Some(from) = from {
            sample[i] = sample[from];
            inv_z[i] = inv_z[from];
        }
    }
}

fn fill_pass(sample: &mut [u32], inv_z: &mut [f32], w: usize, h: usize) {
    // The covered subsample each uncovered one takes, or NONE: u32 indices keep this
    // scratch a quarter of Option<usize>'s size (a view has far fewer subsamples).
    const NONE: u32 = u32::MAX;
    let mut best = vec![NONE; w * h];
    let mut offer = |i: usize, from: u32| {
        let b = best[i];
        if from != NONE && (b == NONE || inv_z[from as usize] < inv_z[b as usize]) {
            best[i] = from;
        }
    };
    let holed: Vec<bool> = sample.chunks_exact(w).map(|r| r.contains(&EMPTY)).collect();
    // Left, then right, then above, then below, for every subsample: at equal depth the
    // first offer stands.
    for y in (0..h).filter(|&y| holed[y]) {
        for reversed in [false, true] {
            let mut last = NONE;
            for k in 0..w {
                let i = y * w + if reversed { w - 1 - k } else { k };
                if sample[i] != EMPTY {
                    last = i as u32;
                } else {
                    offer(i, last);
                }
            }
        }
    }
    // Columns are swept a row at a time, with the last covered subsample of every
    // column at hand: striding down each column missed the cache at every step.
    for reversed in [false, true] {
        let mut last = vec![NONE; w];
        for k in 0..h {
            let y = if reversed { h - 1 - k } else { k };
            let row = y * w;
            if !holed[y] {
                for (x, l) in last.iter_mut().enumerate() {
                    *l = (row + x) as u32;
                }
                continue;
            }
            for (x, l) in last.iter_mut().enumerate() {
                if sample[row + x] != EMPTY {
                    *l = (row + x) as u32;
                } else {
                    offer(row + x, *l);
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
    use super::{
        few_holes, fill_pass, fill_sparse, fill_trapezoid, fill_triangle, outside, Scanlines, EMPTY,
    };

    /// Draws the quad both ways into fresh 40×30 buffers, the trapezoid with the
    /// scanlines of the quads drawn before.
    fn both_ways(q: [[f32; 3]; 4], rows: &mut Scanlines) -> [(Vec<f32>, Vec<u32>); 2] {
        let (w, h) = (40, 30);
        let fresh = || (vec![0.0f32; w * h], vec![EMPTY; w * h]);
        let (mut trapezoid, mut triangles) = (fresh(), fresh());
        assert!(fill_trapezoid(
            q,
            7,
            w,
            h,
            rows,
            &mut trapezoid.0,
            &mut trapezoid.1
        ));
        let [a, b, c, d] = q;
        for tri in [[a, b, c], [b, d, c]] {
            fill_triangle(tri, 7, w, h, &mut triangles.0, &mut triangles.1);
        }
        [trapezoid, triangles]
    }

    #[test]
    fn a_trapezoid_covers_what_its_two_triangles_cover_at_their_depths() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = |lo: f32, hi: f32| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut covered = 0;
        let mut rows = Scanlines::default();
        let (mut top, mut bottom) = (0.0, 0.0);
        for case in 0..500 {
            // Half the cases on the subsample lattice, where centres fall exactly on the
            // diagonal and the edges of neighbouring quads.
            let mut at = |lo: f32, hi: f32| {
                let v = uniform(lo, hi);
                if case % 2 == 0 {
                    v.round()
                } else {
                    v
                }
            };
            // Three quads in a row share their top and bottom, as a photo row's do.
            if case % 3 == 0 {
                (top, bottom) = (at(-3.0, 20.0), at(1.0, 12.0));
            }
            let (ax, cx) = (at(-4.0, 36.0), at(-4.0, 36.0));
            let (bx, dx) = (ax + at(0.0, 6.0), cx + at(0.0, 6.0));
            let mut z = || uniform(0.2, 1.0);
            let q = [
                [ax, top, z()],
                [bx, top, z()],
                [cx, top + bottom, z()],
                [dx, top + bottom, z()],
            ];
            let [(tz, ts), (rz, rs)] = both_ways(q, &mut rows);
            assert_eq!(ts, rs, "{q:?}");
            for (i, (t, r)) in tz.iter().zip(&rz).enumerate() {
                assert!(
                    (t - r).abs() <= 1e-5 * r.abs(),
                    "{q:?} pixel {i}: {t} vs {r}"
                );
            }
            covered += ts.iter().filter(|&&s| s != EMPTY).count();
        }
        assert!(covered > 5_000, "the cases cover pixels: {covered}");
    }

    #[test]
    fn quads_that_are_not_horizontal_trapezoids_are_left_to_the_triangles() {
        let (w, h) = (10, 10);
        let (mut z, mut s) = (vec![0.0f32; w * h], vec![EMPTY; w * h]);
        let slanted = [
            [1.0, 1.0, 1.0],
            [5.0, 2.0, 1.0],
            [1.0, 5.0, 1.0],
            [5.0, 6.0, 1.0],
        ];
        let folded = [
            [5.0, 1.0, 1.0],
            [1.0, 1.0, 1.0],
            [1.0, 5.0, 1.0],
            [5.0, 5.0, 1.0],
        ];
        let behind = [
            [1.0, 1.0, 1.0],
            [5.0, 1.0, 0.0],
            [1.0, 5.0, 1.0],
            [5.0, 5.0, 1.0],
        ];
        for q in [slanted, folded, behind] {
            let rows = &mut Scanlines::default();
            assert!(!fill_trapezoid(q, 1, w, h, rows, &mut z, &mut s), "{q:?}");
        }
        assert!(s.iter().all(|&s| s == EMPTY));
    }

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

    #[test]
    fn walking_from_each_hole_fills_as_the_sweeps_do() {
        let (w, h) = (37, 23);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for case in 0..60 {
            // From a few scattered holes to most of the frame, and blocks of them; depths
            // from a handful of values, so that equal depths (first offer stands) occur.
            let odds = [2, 10, 60, 95][case % 4];
            let block = (next() % 9) as usize;
            let mut sample: Vec<u32> = (0..w * h).map(|i| i as u32).collect();
            for (i, s) in sample.iter_mut().enumerate() {
                let (x, y) = (i % w, i / w);
                let in_block = x / 4 == block && y / 3 == block % 5;
                if next() % 100 < odds || in_block {
                    *s = EMPTY;
                }
            }
            let inv_z: Vec<f32> = (0..w * h)
                .map(|_| (next() % 5) as f32 * 0.25 + 0.1)
                .collect();
            let holes = few_holes(&sample, usize::MAX).unwrap();
            let (mut swept, mut swept_z) = (sample.clone(), inv_z.clone());
            fill_pass(&mut swept, &mut swept_z, w, h);
            let (mut walked, mut walked_z) = (sample.clone(), inv_z.clone());
            fill_sparse(&mut walked, &mut walked_z, w, h, &holes);
            assert_eq!(walked, swept, "case {case}: {} holes", holes.len());
            assert_eq!(walked_z, swept_z, "case {case}");
        }
        let sample = vec![EMPTY, 1, EMPTY, 3];
        assert_eq!(few_holes(&sample, 2), Some(vec![0, 2]));
        assert_eq!(few_holes(&sample, 1), None);
    }
}
