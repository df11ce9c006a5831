//! The background layer behind occluding edges, and its inpainting.
//!
//! From the far side of every cut the background grows under the occluder, breadth
//! first (so each hidden pixel belongs to the nearest background), as far as the widest
//! view can see behind that edge. Depth is continued by linear extrapolation of the
//! background's disparity (planes stay planes), colour by patch-based synthesis: each
//! hidden pixel copies the background pixel whose neighbourhood best matches what is
//! already known around it, trying first the continuation of its neighbours' copies
//! (which extends stripes and edges into the hole rather than smearing them), then a
//! mirror of the background next to it, then random background pixels nearby. Once the
//! band has grown, each pixel chooses again against its whole neighbourhood.
//! Candidates and known pixels are restricted to the background: foreground colours
//! can never be copied into the band.
//!
//! A hidden pixel records the *index* of the pixel it copies, not a colour, so that
//! each view can take the colour from its own reshaded image.

use std::collections::VecDeque;

use super::edges::Cuts;
use super::SplitMix;

/// How many edge thresholds nearer than a band sample a pixel may be and still give
/// it colour. Cuts are steps of at least one threshold between neighbours, while sources
/// lie several pixels away on a possibly sloped background.
const SOURCE_SLOPE_ALLOWANCE: f32 = 3.0;

/// No background sample at this pixel.
pub(super) const NONE: u32 = u32::MAX;

pub(super) struct Band {
    /// Per pixel: index into `disparity` and `source`, or [`NONE`].
    pub at: Vec<u32>,
    pub disparity: Vec<f32>,
    pub source: Vec<u32>,
}

pub(super) struct BandInput<'a> {
    pub width: usize,
    pub height: usize,
    pub disparity: &'a [f32],
    /// Interleaved RGB of the build image.
    pub colours: &'a [f32],
    pub cuts: &'a Cuts,
    /// Band width in pixels per unit disparity step (focal length × widest offset).
    pub px_per_disparity: f64,
    pub max_band_px: usize,
    pub threshold: f32,
    pub patch_radius: usize,
    pub random_candidates: usize,
}

impl BandInput<'_> {
    fn colour(&self, i: usize) -> [f32; 3] {
        [
            self.colours[3 * i],
            self.colours[3 * i + 1],
            self.colours[3 * i + 2],
        ]
    }

    /// Whether the original pixel `i` lies on or behind a surface of disparity `d`.
    fn behind_or_on(&self, i: usize, d: f32) -> bool {
        self.disparity[i] <= d * (1.0 + self.threshold)
    }

    /// Whether the original pixel `i` may give its colour to a band sample of
    /// disparity `d`: like [`Self::behind_or_on`], with room for the background's own
    /// slope between the two pixels (a floor or a wall seen at an angle is nearer
    /// above or beside the band than in it), but never an occluder's step.
    fn colour_source(&self, i: usize, d: f32) -> bool {
        self.disparity[i] <= d * (1.0 + SOURCE_SLOPE_ALLOWANCE * self.threshold)
    }

    /// Whether a band sample of disparity `b` lies on the surface of one of disparity
    /// `d`, with the room [`Self::colour_source`] gives the background, so that band
    /// samples and background pixels join a mean on the same terms.
    fn same_surface(&self, b: f32, d: f32) -> bool {
        (b - d).abs() <= SOURCE_SLOPE_ALLOWANCE * self.threshold * d
    }

    fn neighbours4(&self, i: usize) -> impl Iterator<Item = usize> {
        let (w, h) = (self.width, self.height);
        let (x, y) = (i % w, i / w);
        [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ]
        .into_iter()
        .flatten()
    }
}

/// Grows and inpaints the band behind every cut.
pub(super) fn grow(input: &BandInput) -> Band {
    let mut band = spread(input);
    refine(&mut band, input);
    band
}

/// The band grown breadth first, each pixel copying what best continues the
/// neighbours filled before it.
fn spread(input: &BandInput) -> Band {
    let mut band = Band {
        at: vec![NONE; input.width * input.height],
        disparity: Vec::new(),
        source: Vec::new(),
    };
    let mut queue = seeds(input);
    while let Some((p, budget, surface, copied)) = queue.pop_front() {
        if budget == 0 {
            continue;
        }
        for r in input.neighbours4(p) {
            if band.at[r] != NONE || input.behind_or_on(r, surface) {
                continue;
            }
            let d = extrapolate_disparity(&band, input, r, surface);
            if input.behind_or_on(r, d) {
                continue;
            }
            let source = best_source(&band, input, r, d, budget).unwrap_or(copied);
            band.at[r] = band.disparity.len() as u32;
            band.disparity.push(d);
            band.source.push(source);
            queue.push_back((r, budget - 1, d, source));
        }
    }
    band
}

/// A second pass over the band once it has grown. Growing, a pixel chooses its source
/// from the few neighbours filled before it, so two fronts meeting in the middle of a
/// band each continue their own copy and leave a seam. Once every pixel has a source,
/// each keeps it unless a candidate matches its whole neighbourhood better: its
/// neighbours' copies continued or mirrored, and random pixels at halving distances
/// around the current source (PatchMatch's search). One pass takes most of what passes
/// give: a second moved the held-out renders' uncovered regions by under 0.1 dB.
fn refine(band: &mut Band, input: &BandInput) {
    let w = input.width as i64;
    for r in 0..band.at.len() {
        if band.at[r] == NONE {
            continue;
        }
        let k = band.at[r] as usize;
        let d = band.disparity[k];
        let (rx, ry) = ((r as i64) % w, (r as i64) / w);
        let mut target = known_patch(band, input, rx, ry, d);
        target.retain(|&(dx, dy, _)| dx != 0 || dy != 0);
        let current = band.source[k] as i64;
        let mut best = (
            patch_distance(input, &target, current % w, current / w, d),
            band.source[k],
        );
        for m in input.neighbours4(r) {
            let n = band.at[m];
            if n == NONE {
                continue;
            }
            let offset = (rx - (m as i64) % w, ry - (m as i64) / w);
            for at in copies(band.source[n as usize], w, offset) {
                consider(input, &target, d, at, &mut best);
            }
        }
        let mut rng = SplitMix(r as u64 ^ 0x5851_f42d_4c95_7f2d);
        let mut radius = (2 * input.patch_radius + 8) as i64;
        while radius >= 1 {
            let (cx, cy) = (best.1 as i64 % w, best.1 as i64 / w);
            let (dx, dy) = rng.offset(radius);
            consider(input, &target, d, (cx + dx, cy + dy), &mut best);
            radius /= 2;
        }
        band.source[k] = best.1;
    }
}

/// Per band sample, how far its copied colour lies from the mean colour of the surface
/// around it (band samples of about its disparity and background pixels behind or on
/// it, within `radius` px): added to the copy in every view, it averages the band over
/// that box. Patch synthesis copies texture that is plausible but not the hidden one;
/// its mean lies nearer the truth (+0.3 to +0.75 dB in the uncovered regions of held-out
/// renders with true depth, docs/relocation.md) and its seams and repeated rows soften.
/// Empty when `radius` is 0.
pub(super) fn smoothing(band: &Band, input: &BandInput, radius: usize) -> Vec<[f32; 3]> {
    if radius == 0 {
        return Vec::new();
    }
    let mut pixel_of = vec![0usize; band.disparity.len()];
    for (p, &k) in band.at.iter().enumerate().filter(|(_, &k)| k != NONE) {
        pixel_of[k as usize] = p;
    }
    let copied = |k: usize| input.colour(band.source[k] as usize);
    let (w, h) = (input.width, input.height);
    pixel_of
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            let d = band.disparity[k];
            let (px, py) = (p % w, p / w);
            let own = copied(k);
            let (mut sum, mut n) = (own, 1.0f32);
            for y in py.saturating_sub(radius)..(py + radius + 1).min(h) {
                for x in px.saturating_sub(radius)..(px + radius + 1).min(w) {
                    let i = y * w + x;
                    let colour = match band.at[i] {
                        NONE if input.colour_source(i, d) => input.colour(i),
                        b if b != NONE
                            && b as usize != k
                            && input.same_surface(band.disparity[b as usize], d) =>
                        {
                            copied(b as usize)
                        }
                        _ => continue,
                    };
                    sum.iter_mut().zip(colour).for_each(|(s, c)| *s += c);
                    n += 1.0;
                }
            }
            std::array::from_fn(|c| sum[c] / n - own[c])
        })
        .collect()
}

/// The far pixel of every cut, with the band width its edge needs, the disparity of the
/// surface to extend (the far pixel's own, even where it is an occluder itself) and the
/// background pixel the band copies when nothing better is found (the far pixel).
fn seeds(input: &BandInput) -> VecDeque<(usize, usize, f32, u32)> {
    let mut budget = vec![0usize; input.width * input.height];
    for (near, far) in input.cuts.pairs(input.disparity) {
        let step = f64::from(input.disparity[near] - input.disparity[far]);
        // In floating point until bounded: a far camera makes the product huge or NaN.
        let px = ((step * input.px_per_disparity).ceil().max(0.0) + 2.0)
            .min(input.max_band_px as f64) as usize;
        budget[far] = budget[far].max(px);
    }
    budget
        .iter()
        .enumerate()
        .filter(|(_, &b)| b > 0)
        .map(|(i, &b)| (i, b, input.disparity[i], i as u32))
        .collect()
}

/// The disparity of the sample at pixel `i` that lies on the surface of disparity
/// about `d` (its band sample or its original pixel), if either does.
fn settled(band: &Band, input: &BandInput, i: usize, d: f32) -> Option<f32> {
    let on_surface = |b: f32| (b - d).abs() <= 2.0 * input.threshold * d.max(b);
    let back = match band.at[i] {
        NONE => None,
        k => Some(band.disparity[k as usize]).filter(|&b| on_surface(b)),
    };
    back.or_else(|| Some(input.disparity[i]).filter(|&b| on_surface(b)))
}

/// Continues the background's disparity into pixel `r`: from each settled neighbour,
/// linear extrapolation along the line through it when the pixel beyond is settled
/// too, its own value otherwise; the predictions are averaged.
fn extrapolate_disparity(band: &Band, input: &BandInput, r: usize, surface: f32) -> f32 {
    let w = input.width as i64;
    let (rx, ry) = ((r as i64) % w, (r as i64) / w);
    let at = |x: i64, y: i64| {
        (x >= 0 && y >= 0 && x < w && y < input.height as i64).then(|| (y * w + x) as usize)
    };
    let (mut sum, mut count) = (0.0f32, 0);
    for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
        let Some(m) = at(rx + dx, ry + dy) else {
            continue;
        };
        let Some(dm) = settled(band, input, m, surface) else {
            continue;
        };
        let beyond = at(rx + 2 * dx, ry + 2 * dy).and_then(|b| settled(band, input, b, surface));
        let predicted = beyond.map_or(dm, |db| (2.0 * dm - db).clamp(0.5 * dm, 1.5 * dm));
        sum += predicted;
        count += 1;
    }
    if count == 0 {
        surface
    } else {
        sum / count as f32
    }
}

/// The background pixel whose neighbourhood best matches the known neighbourhood of
/// `r`, if any candidate is background.
fn best_source(band: &Band, input: &BandInput, r: usize, d: f32, reach: usize) -> Option<u32> {
    let w = input.width as i64;
    let (rx, ry) = ((r as i64) % w, (r as i64) / w);
    let target = known_patch(band, input, rx, ry, d);
    let mut best = (f32::INFINITY, NONE);
    let mut consider = |at: (i64, i64)| consider(input, &target, d, at, &mut best);
    for m in input.neighbours4(r) {
        let (mx, my) = ((m as i64) % w, (m as i64) / w);
        let (ox, oy) = (rx - mx, ry - my);
        match band.at[m] {
            // Coherence: continue the neighbour's copy with the same offset, or its
            // mirror image: growing away from the background the same offset soon walks
            // off the background's edge, and the mirror walks back into it instead.
            k if k != NONE => {
                for at in copies(band.source[k as usize], w, (ox, oy)) {
                    consider(at);
                }
            }
            // Background next to the hole: itself and its mirror image across r's edge.
            _ if input.colour_source(m, d) => {
                consider((mx, my));
                consider((mx - ox, my - oy));
            }
            _ => {}
        }
    }
    let radius = (2 * reach + input.patch_radius + 1) as i64;
    let mut rng = SplitMix(r as u64 ^ 0x9e37_79b9_7f4a_7c15);
    for _ in 0..input.random_candidates {
        let (dx, dy) = rng.offset(radius);
        consider((rx + dx, ry + dy));
    }
    (best.1 != NONE).then_some(best.1)
}

/// Where a neighbour's copy from `source` continues at a pixel `offset` away from it, and
/// that position's mirror image about the source.
fn copies(source: u32, w: i64, (ox, oy): (i64, i64)) -> [(i64, i64); 2] {
    let (sx, sy) = (source as i64 % w, source as i64 / w);
    [(sx + ox, sy + oy), (sx - ox, sy - oy)]
}

/// Takes the background pixel at `at` as `best` (score, pixel) when its neighbourhood
/// matches `target` better.
fn consider(
    input: &BandInput,
    target: &[(i64, i64, [f32; 3])],
    d: f32,
    (sx, sy): (i64, i64),
    best: &mut (f32, u32),
) {
    let (w, h) = (input.width as i64, input.height as i64);
    if sx < 0 || sy < 0 || sx >= w || sy >= h {
        return;
    }
    let s = (sy * w + sx) as usize;
    if !input.colour_source(s, d) || best.1 == s as u32 {
        return;
    }
    let score = patch_distance(input, target, sx, sy, d);
    if score < best.0 {
        *best = (score, s as u32);
    }
}

/// Known colours around (x, y) as (dx, dy, colour): background pixels and band pixels.
fn known_patch(
    band: &Band,
    input: &BandInput,
    x: i64,
    y: i64,
    d: f32,
) -> Vec<(i64, i64, [f32; 3])> {
    let (w, h) = (input.width as i64, input.height as i64);
    let r = input.patch_radius as i64;
    let mut known = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    for dy in -r..=r {
        for dx in -r..=r {
            let (px, py) = (x + dx, y + dy);
            if px < 0 || py < 0 || px >= w || py >= h {
                continue;
            }
            let p = (py * w + px) as usize;
            match band.at[p] {
                NONE if input.colour_source(p, d) => known.push((dx, dy, input.colour(p))),
                NONE => {}
                k => known.push((dx, dy, input.colour(band.source[k as usize] as usize))),
            }
        }
    }
    known
}

/// Mean squared colour difference over the known offsets, foreground pixels around the
/// source counting as a full mismatch, plus a penalty for a different depth.
fn patch_distance(
    input: &BandInput,
    target: &[(i64, i64, [f32; 3])],
    sx: i64,
    sy: i64,
    d: f32,
) -> f32 {
    let (w, h) = (input.width as i64, input.height as i64);
    let mut sum = 0.0;
    for &(dx, dy, c) in target {
        let (px, py) = ((sx + dx).clamp(0, w - 1), (sy + dy).clamp(0, h - 1));
        let p = (py * w + px) as usize;
        sum += if input.colour_source(p, d) {
            let s = input.colour(p);
            (0..3).map(|k| (s[k] - c[k]).powi(2)).sum::<f32>()
        } else {
            3.0
        };
    }
    let s = (sy * w + sx) as usize;
    let depth_penalty = ((input.disparity[s] - d) / d.max(1e-6)).powi(2);
    sum / target.len().max(1) as f32 + depth_penalty
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 48;
    const H: usize = 40;

    /// A wall (colour per pixel from `wall`) behind a near square of colour `front`,
    /// handed to `look` as the band's input.
    fn behind_a_square<T>(
        mut wall: impl FnMut(usize) -> [f32; 3],
        front: [f32; 3],
        look: impl FnOnce(&BandInput) -> T,
    ) -> T {
        let near = |i: usize| (16..32).contains(&(i % W)) && (12..28).contains(&(i / W));
        let disparity: Vec<f32> = (0..W * H)
            .map(|i| if near(i) { 0.8 } else { 0.2 })
            .collect();
        let colours: Vec<f32> = (0..W * H)
            .flat_map(|i| {
                // Drawn for every pixel, hidden or not, so that a noisy wall's draws do
                // not depend on where the square lies.
                let behind = wall(i);
                if near(i) {
                    front
                } else {
                    behind
                }
            })
            .collect();
        let cuts = super::super::edges::detect(&disparity, W, H, 0.04, 6);
        look(&BandInput {
            width: W,
            height: H,
            disparity: &disparity,
            colours: &colours,
            cuts: &cuts,
            px_per_disparity: 10.0,
            max_band_px: 256,
            threshold: 0.04,
            patch_radius: 2,
            random_candidates: 6,
        })
    }

    /// A far wall of diagonal stripes (three colours, each stripe two pixels wide)
    /// behind a near square: the share of band pixels whose copied colour is the
    /// stripe the wall has there.
    fn stripes_behind_a_square(refined: bool) -> f64 {
        let stripe = |i: usize| ((i % W) / 2 + i / W) % 3;
        let palette = [[0.9, 0.2, 0.1], [0.1, 0.7, 0.2], [0.2, 0.3, 0.9]];
        let band = behind_a_square(
            |i| palette[stripe(i)],
            [0.5; 3],
            |input| {
                let mut band = spread(input);
                if refined {
                    refine(&mut band, input);
                }
                band
            },
        );
        let filled: Vec<usize> = (0..W * H).filter(|&p| band.at[p] != NONE).collect();
        assert!(
            filled.len() > 150,
            "the band covers {} pixels",
            filled.len()
        );
        let right = filled
            .iter()
            .filter(|&&p| stripe(band.source[band.at[p] as usize] as usize) == stripe(p))
            .count();
        right as f64 / filled.len() as f64
    }

    /// A grey wall of noisy pixels behind a pure red square, inpainted: per band sample
    /// its colour as copied and with `smoothing` added.
    fn noisy_wall_band(radius: usize) -> Vec<([f32; 3], [f32; 3])> {
        let mut rng = SplitMix(7);
        let grey = move |_| [0.3 + 0.4 * (rng.next() % 1000) as f32 / 1000.0; 3];
        behind_a_square(grey, [1.0, 0.0, 0.0], |input| {
            let band = grow(input);
            let shade = smoothing(&band, input, radius);
            (0..band.disparity.len())
                .map(|k| {
                    let copied = input.colour(band.source[k] as usize);
                    let offset = shade.get(k).copied().unwrap_or_default();
                    (copied, std::array::from_fn(|c| copied[c] + offset[c]))
                })
                .collect()
        })
    }

    #[test]
    fn smoothing_calms_copied_noise_without_the_occluders_colour() {
        assert!(noisy_wall_band(0).iter().all(|(a, b)| a == b));
        let band = noisy_wall_band(3);
        assert!(band.len() > 150, "the band holds {} samples", band.len());
        let spread = |colours: Vec<[f32; 3]>| {
            colours.iter().map(|c| (c[1] - 0.5).powi(2)).sum::<f32>() / colours.len() as f32
        };
        let copied = spread(band.iter().map(|s| s.0).collect());
        let smoothed = spread(band.iter().map(|s| s.1).collect());
        assert!(
            smoothed < 0.2 * copied,
            "variance about the wall's mean: copied {copied:.5}, smoothed {smoothed:.5}"
        );
        for (_, c) in &band {
            assert!(
                c[0] - c[1] < 1e-4 && (0.3..=0.7).contains(&c[1]),
                "band colour {c:?} is not the wall's grey"
            );
        }
    }

    #[test]
    fn refining_continues_stripes_where_fronts_meet() {
        let greedy = stripes_behind_a_square(false);
        let refined = stripes_behind_a_square(true);
        assert!(
            refined > 0.99,
            "{refined:.3} of the band continues the stripes"
        );
        assert!(refined > greedy, "refined {refined:.3}, greedy {greedy:.3}");
    }
}
