//! Edge-aware refinement of upsampled depth, with the photo as guide: a joint (colour-
//! weighted) median of the disparity. Each pixel takes the weighted median of the
//! disparities around it, weighted by how close their photo colour is to its own.
//!
//! Why a median and not a guided filter or a joint bilateral mean: an upsampled 384-px
//! network output has ramps several photo pixels wide across every depth edge, and a
//! few of them off the photo's edge. Averaging filters put a step on the photo edge but
//! keep the ramp's wrong values beside it; a colour-weighted median over a window wider
//! than the ramp replaces them by the plateau of the pixel's own colour region, so the
//! depth edge lands on the image edge and no in-between depths (the stretched "rubber
//! sheet" pixels of 3D photos) remain. It never creates values that are not in its input.
//! Structures thinner than half the window whose colour matches their surroundings are
//! lost; that is the price.
//!
//! It runs on disparity (what the views interpolate).

/// How the refinement looks around each pixel.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct RefineOptions {
    /// Window radius in working pixels; must exceed the width of the upsampled ramps.
    pub radius: usize,
    /// Colour distance (RGB in [0, 1], Euclidean) at which a neighbour's weight halves.
    pub sigma_color: f32,
    /// The refinement runs on the photo shrunk so its longer side is at most this.
    pub max_side: usize,
}

/// A window whose disparities all lie within this fraction of the largest is left as
/// it is (the pixel keeps its own value): a quarter of the LDI's smallest depth step, so
/// no edge is skipped, and most pixels of a photo are spared the median.
const FLAT: f32 = 0.01;

/// Taps per side of the window: every pixel of a window up to this radius counts (a
/// sparser grid skips the pixels beside the edge, the ones that decide where it lands:
/// it cost 0.2-0.5 dB near depth edges in `eval-relocation --depth-source coarse`);
/// wider windows are sampled on a (2·TAPS+1)² grid so that the cost per pixel stays
/// bounded.
const TAPS: usize = 8;

impl Default for RefineOptions {
    fn default() -> Self {
        Self {
            radius: 0,
            sigma_color: 0.1,
            max_side: 1024,
        }
    }
}

impl RefineOptions {
    /// The radius for depth upsampled from a `net_long`-px map to `work_long` px: two
    /// source pixels, about the width of a network's edge ramp (three were measured
    /// 0.2 dB worse near depth edges at a third of the photo's size: a wider window
    /// lets more of the far side's colour-alike pixels vote).
    pub fn radius_for(net_long: usize, work_long: usize) -> usize {
        let factor = work_long as f64 / net_long.max(1) as f64;
        ((2.0 * factor).ceil() as usize).max(2)
    }
}

/// Refines `disparity` (`width`×`height`, row-major) with the interleaved RGB photo `rgb`
/// (values in [0, 1]) of the same size, in bands of rows on every core.
pub fn refine_disparity(
    rgb: &[f32],
    disparity: &[f32],
    width: usize,
    height: usize,
    opts: RefineOptions,
) -> Vec<f32> {
    assert_eq!(rgb.len(), 3 * width * height, "guide does not match size");
    assert_eq!(
        disparity.len(),
        width * height,
        "disparity does not match size"
    );
    let mut out = vec![0.0; width * height];
    crate::parallel::bands(
        crate::parallel::cores(),
        height,
        width,
        &mut out,
        |y0, band| {
            for (k, row) in band.chunks_exact_mut(width).enumerate() {
                refine_row(rgb, disparity, (width, height), y0 + k, opts, row);
            }
        },
    );
    out
}

/// Row `y` of [`refine_disparity`] into `out`.
fn refine_row(
    rgb: &[f32],
    disparity: &[f32],
    (width, height): (usize, usize),
    y: usize,
    opts: RefineOptions,
    out: &mut [f32],
) {
    let r = opts.radius.max(1);
    let stride = r.div_ceil(TAPS).max(1);
    let inv_s2 = 1.0 / (opts.sigma_color * opts.sigma_color).max(1e-12);
    let mut taps: Vec<(f32, f32)> = Vec::with_capacity((2 * TAPS + 1).pow(2));
    for (x, refined) in out.iter_mut().enumerate() {
        let taps_at = || window((x, y), (width, height), r, stride);
        let (lo, hi) = taps_at().fold((f32::INFINITY, 0.0f32), |(lo, hi), j| {
            (lo.min(disparity[j]), hi.max(disparity[j]))
        });
        let centre = y * width + x;
        if hi - lo <= FLAT * hi {
            *refined = disparity[centre];
            continue;
        }
        let me = &rgb[3 * centre..3 * centre + 3];
        taps.clear();
        taps.extend(taps_at().map(|j| {
            let c = &rgb[3 * j..3 * j + 3];
            let d2 = (c[0] - me[0]).powi(2) + (c[1] - me[1]).powi(2) + (c[2] - me[2]).powi(2);
            (disparity[j], 1.0 / (1.0 + d2 * inv_s2))
        }));
        *refined = weighted_median(&mut taps);
    }
}

/// The indices of the window's taps around `(x, y)`: every `stride`-th pixel within
/// `r`, on multiples of the stride so that the window is symmetric and holds the pixel
/// itself, clipped to the image.
fn window(
    (x, y): (usize, usize),
    (width, height): (usize, usize),
    r: usize,
    stride: usize,
) -> impl Iterator<Item = usize> {
    let reach = r / stride * stride;
    let span = move |c: usize, n: usize| {
        let first = c - (c.min(reach) / stride) * stride;
        (first..=(c + reach).min(n - 1)).step_by(stride)
    };
    span(y, height).flat_map(move |yy| span(x, width).map(move |xx| yy * width + xx))
}

/// The first value, in ascending order, at which the running sum of weights reaches
/// half the total. Found by repeated selection instead of a sort: each round places one
/// pivot and keeps the side that holds the half-way point, linear time on average.
fn weighted_median(taps: &mut [(f32, f32)]) -> f32 {
    let half = taps.iter().map(|t| t.1).sum::<f32>() / 2.0;
    let (mut lo, mut hi, mut below) = (0, taps.len(), 0.0);
    while hi - lo > 1 {
        let k = (hi - lo) / 2;
        let (left, pivot, _) = taps[lo..hi].select_nth_unstable_by(k, |a, b| a.0.total_cmp(&b.0));
        let left_weight: f32 = left.iter().map(|t| t.1).sum();
        if below + left_weight >= half {
            hi = lo + k;
        } else if below + left_weight + pivot.1 >= half {
            return pivot.0;
        } else {
            below += left_weight + pivot.1;
            lo += k + 1;
        }
    }
    // Past the end only by rounding: the next value in order is the pivot a previous
    // round left at `lo` (or the largest, the last).
    taps.get(lo.min(taps.len().saturating_sub(1)))
        .map_or(0.0, |t| t.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_median_follows_the_weights() {
        let mut t = vec![(3.0, 1.0), (1.0, 1.0), (2.0, 5.0)];
        assert_eq!(weighted_median(&mut t), 2.0);
        let mut t = vec![(3.0, 10.0), (1.0, 1.0), (2.0, 1.0)];
        assert_eq!(weighted_median(&mut t), 3.0);
    }

    /// A reproducible stream of numbers in [0, 1) from `seed`.
    fn uniform(mut state: u32) -> impl FnMut() -> f32 {
        move || {
            state = state.wrapping_mul(1664525).wrapping_add(1013904223);
            (state >> 8) as f32 / (1 << 24) as f32
        }
    }

    #[test]
    fn selection_finds_what_sorting_finds() {
        let mut next = uniform(12345);
        for n in 1..90 {
            // Few distinct values, as on a depth plateau, and weights far apart.
            let taps: Vec<(f32, f32)> = (0..n)
                .map(|_| ((next() * 6.0).floor(), 0.01 + next() * next() * 10.0))
                .collect();
            let mut sorted = taps.clone();
            sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
            let half = sorted.iter().map(|t| t.1).sum::<f32>() / 2.0;
            let mut acc = 0.0;
            let want = sorted
                .iter()
                .find(|t| {
                    acc += t.1;
                    acc >= half
                })
                .map_or(sorted[n - 1].0, |t| t.0);
            assert_eq!(weighted_median(&mut taps.clone()), want, "{taps:?}");
        }
        assert_eq!(weighted_median(&mut []), 0.0);
    }

    #[test]
    fn windows_up_to_the_cap_count_every_pixel() {
        let (w, h) = (23, 17);
        let mut next = uniform(99);
        let rgb: Vec<f32> = (0..3 * w * h).map(|_| next()).collect();
        let disparity: Vec<f32> = (0..w * h).map(|_| (next() * 8.0).floor()).collect();
        let opts = RefineOptions {
            radius: TAPS,
            ..RefineOptions::default()
        };
        let out = refine_disparity(&rgb, &disparity, w, h, opts);
        let r = TAPS as isize;
        let inv_s2 = 1.0 / (opts.sigma_color * opts.sigma_color);
        for (i, &got) in out.iter().enumerate() {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let me = &rgb[3 * i..3 * i + 3];
            let mut taps = Vec::new();
            for yy in (y - r).max(0)..=(y + r).min(h as isize - 1) {
                for xx in (x - r).max(0)..=(x + r).min(w as isize - 1) {
                    let j = yy as usize * w + xx as usize;
                    let d2: f32 = (0..3).map(|c| (rgb[3 * j + c] - me[c]).powi(2)).sum();
                    taps.push((disparity[j], 1.0 / (1.0 + d2 * inv_s2)));
                }
            }
            assert_eq!(got, weighted_median(&mut taps), "pixel ({x}, {y})");
        }
    }

    #[test]
    fn only_windows_with_a_step_are_refined() {
        // A photo edge at x = 8 with a disparity step of 0.5 % there (left alone) and
        // of 2 % (put where the pixel's colour says, here one pixel further right).
        let (w, h) = (16, 5);
        let rgb: Vec<f32> = (0..w * h)
            .flat_map(|i| if i % w < 8 { [0.1; 3] } else { [0.9; 3] })
            .collect();
        let step = |size: f32| -> Vec<f32> {
            (0..w * h)
                .map(|i| if i % w < 9 { 1.0 + size } else { 1.0 })
                .collect()
        };
        let opts = RefineOptions {
            radius: 2,
            ..RefineOptions::default()
        };
        let small = step(0.005);
        assert_eq!(refine_disparity(&rgb, &small, w, h, opts), small);
        let out = refine_disparity(&rgb, &step(0.02), w, h, opts);
        assert_eq!(out[2 * w + 7], 1.02);
        assert_eq!(out[2 * w + 8], 1.0);
    }

    #[test]
    fn the_radius_is_two_network_pixels() {
        // A 384-px output on the Portrait's 560-px views, on a 747-px working size, and
        // shrunk to 128 px.
        assert_eq!(RefineOptions::radius_for(384, 560), 3);
        assert_eq!(RefineOptions::radius_for(384, 747), 4);
        assert_eq!(RefineOptions::radius_for(384, 128), 2);
    }

    #[test]
    fn uniform_photo_keeps_a_monotone_ramp_monotone() {
        let (w, h) = (16, 3);
        let rgb = vec![0.5; 3 * w * h];
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32).collect();
        let opts = RefineOptions {
            radius: 2,
            ..RefineOptions::default()
        };
        let out = refine_disparity(&rgb, &ramp, w, h, opts);
        // A median of a linear ramp over a symmetric window is the centre value.
        for x in 2..14 {
            assert_eq!(out[w + x], ramp[w + x]);
        }
    }
}
