//! Filling what a view sees and no sample covers (beyond the photo's frame with
//! [`super::Border::Inpaint`], or a disocclusion wider than the band) by patch
//! synthesis in the rendered view, instead of repeating the pixel at the hole's edge,
//! which draws streaks as long as the hole is wide.
//!
//! Holes are peeled from their edge inwards; each pixel copies the known pixel whose
//! neighbourhood best matches its own known neighbourhood, trying the continuation of
//! its neighbours' copies first (coherent texture), then the mirror image of the known
//! pixels beside it, then random known pixels nearby. Only pixels at least as far as the
//! surface the hole opened onto may give colour, so an occluder is never copied into
//! what it uncovers.

use std::collections::VecDeque;

use super::SplitMix;

/// Patch half-size.
const PATCH: i64 = 2;
/// Random candidates per pixel besides the coherent and mirrored ones.
const RANDOM: usize = 8;
/// How much nearer (relative 1/z) than the hole's surface a source may be.
const NEARER: f32 = 0.12;

/// Fills the pixels of `hole` in `rgb` (interleaved, `w`×`h`). `inv_z` is 1/z per
/// pixel: for known pixels their surface's, for hole pixels that of the surface the hole
/// opened onto (the farthest beside it).
pub(super) fn synthesize(rgb: &mut [f32], inv_z: &[f32], hole: &[bool], w: usize, h: usize) {
    let mut known: Vec<bool> = hole.iter().map(|&o| !o).collect();
    if known.iter().all(|&k| k) || !known.iter().any(|&k| k) {
        return;
    }
    let mut source = vec![usize::MAX; w * h];
    let mut rng = SplitMix(0x5eed);
    for p in peel_order(&known, w, h) {
        let (px, py) = ((p % w) as i64, (p / w) as i64);
        let may_give = |s: usize| known[s] && inv_z[s] <= inv_z[p] * (1.0 + NEARER);
        let mut candidates: Vec<(i64, i64)> = Vec::with_capacity(16);
        for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let (mx, my) = (px + dx, py + dy);
            if mx < 0 || my < 0 || mx >= w as i64 || my >= h as i64 {
                continue;
            }
            let m = my as usize * w + mx as usize;
            if source[m] != usize::MAX {
                let s = source[m];
                candidates.push(((s % w) as i64 - dx, (s / w) as i64 - dy));
            } else if known[m] && !hole[m] {
                candidates.push((mx, my));
                candidates.push((mx + dx, my + dy));
            }
        }
        let radius = 4 * PATCH + 2 * distance_to_known(&known, px, py, w, h);
        for _ in 0..RANDOM {
            let (dx, dy) = rng.offset(radius);
            candidates.push((px + dx, py + dy));
        }
        let mut best = (f32::INFINITY, usize::MAX);
        for (sx, sy) in candidates {
            if sx < 0 || sy < 0 || sx >= w as i64 || sy >= h as i64 {
                continue;
            }
            let s = sy as usize * w + sx as usize;
            if hole[s] || !may_give(s) {
                continue;
            }
            let cost = patch_cost(rgb, &known, hole, (px, py), (sx, sy), w, h);
            if cost < best.0 {
                best = (cost, s);
            }
        }
        if best.1 == usize::MAX {
            continue;
        }
        let s = best.1;
        for c in 0..3 {
            rgb[3 * p + c] = rgb[3 * s + c];
        }
        source[p] = s;
        known[p] = true;
    }
}

/// Hole pixels in breadth-first order from the known pixels (nearest first).
fn peel_order(known: &[bool], w: usize, h: usize) -> Vec<usize> {
    let mut seen = known.to_vec();
    let mut queue: VecDeque<usize> = (0..w * h).filter(|&i| known[i]).collect();
    let mut order = Vec::new();
    while let Some(i) = queue.pop_front() {
        let (x, y) = (i % w, i / w);
        let next = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ];
        for j in next.into_iter().flatten() {
            if !seen[j] {
                seen[j] = true;
                order.push(j);
                queue.push_back(j);
            }
        }
    }
    order
}

/// Chebyshev distance to the nearest known pixel within a small search (capped).
fn distance_to_known(known: &[bool], x: i64, y: i64, w: usize, h: usize) -> i64 {
    const CAP: i64 = 32;
    for r in 1..CAP {
        for (dx, dy) in (-r..=r).flat_map(|d| [(d, -r), (d, r), (-r, d), (r, d)]) {
            let (sx, sy) = (x + dx, y + dy);
            if sx >= 0
                && sy >= 0
                && sx < w as i64
                && sy < h as i64
                && known[sy as usize * w + sx as usize]
            {
                return r;
            }
        }
    }
    CAP
}

/// Mean squared colour difference between the known pixels around `p` and the pixels
/// at the same offsets around `s`; offsets where `s`'s side is a hole count fully.
fn patch_cost(
    rgb: &[f32],
    known: &[bool],
    hole: &[bool],
    (px, py): (i64, i64),
    (sx, sy): (i64, i64),
    w: usize,
    h: usize,
) -> f32 {
    let (mut sum, mut count) = (0.0f32, 0usize);
    for dy in -PATCH..=PATCH {
        for dx in -PATCH..=PATCH {
            let (ax, ay) = (px + dx, py + dy);
            if ax < 0 || ay < 0 || ax >= w as i64 || ay >= h as i64 {
                continue;
            }
            let a = ay as usize * w + ax as usize;
            if !known[a] {
                continue;
            }
            let (bx, by) = (
                (sx + dx).clamp(0, w as i64 - 1),
                (sy + dy).clamp(0, h as i64 - 1),
            );
            let b = by as usize * w + bx as usize;
            count += 1;
            sum += if hole[b] {
                3.0
            } else {
                (0..3)
                    .map(|c| (rgb[3 * a + c] - rgb[3 * b + c]).powi(2))
                    .sum()
            };
        }
    }
    sum / count.max(1) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A diagonal stripe texture whose left 6 columns are a hole, as at a frame edge.
    fn striped(w: usize, h: usize) -> (Vec<f32>, Vec<bool>) {
        let mut rgb = vec![0.0; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let v = if (x + y) / 2 % 2 == 0 { 0.9 } else { 0.1 };
                rgb[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[v, 0.5, 1.0 - v]);
            }
        }
        let hole = (0..w * h).map(|i| i % w < 6).collect();
        (rgb, hole)
    }

    #[test]
    fn a_hole_at_the_edge_continues_the_texture_instead_of_repeating_a_column() {
        let (w, h) = (32, 24);
        let (truth, hole) = striped(w, h);
        let mut rgb = truth.clone();
        for i in (0..w * h).filter(|&i| hole[i]) {
            rgb[3 * i..3 * i + 3].copy_from_slice(&[0.0; 3]);
        }
        synthesize(&mut rgb, &vec![1.0; w * h], &hole, w, h);
        // Streaks: each hole row a copy of its edge pixel. A texture: rows vary.
        let streaked = (0..h).all(|y| (0..6).all(|x| rgb[3 * (y * w + x)] == rgb[3 * (y * w + 6)]));
        assert!(
            !streaked,
            "the hole was filled by repeating the edge column"
        );
        let wrong = (0..w * h)
            .filter(|&i| hole[i] && (rgb[3 * i] - truth[3 * i]).abs() > 0.4)
            .count();
        assert!(
            wrong * 10 < 6 * h,
            "{wrong} of {} hole pixels off the stripes",
            6 * h
        );
    }

    #[test]
    fn nearer_pixels_never_give_colour() {
        // Left half near (1/z = 1, red), right half far (1/z = 0.25, blue) with a hole
        // opening onto the far side.
        let (w, h) = (16, 8);
        let mut rgb = vec![0.0; 3 * w * h];
        let mut inv_z = vec![0.25; w * h];
        for i in 0..w * h {
            if i % w < 8 {
                rgb[3 * i] = 1.0;
                inv_z[i] = 1.0;
            } else {
                rgb[3 * i + 2] = 1.0;
            }
        }
        let hole: Vec<bool> = (0..w * h).map(|i| (8..11).contains(&(i % w))).collect();
        synthesize(&mut rgb, &inv_z, &hole, w, h);
        for i in (0..w * h).filter(|&i| hole[i]) {
            assert_eq!(&rgb[3 * i..3 * i + 3], &[0.0, 0.0, 1.0], "pixel {i}");
        }
    }
}
