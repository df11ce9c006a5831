//! Edge refinement on a synthetic step edge: the photo steps from dark to bright at
//! x = 32, the depth steps there too but arrives the way an upsampled network output
//! does — as an 8-pixel ramp, centred 3 pixels off the photo's edge. After refinement
//! the depth must step exactly at the photo's edge, with no in-between values left.

use reshader::depth::refine::{refine_disparity, RefineOptions};

const W: usize = 64;
const H: usize = 24;
const EDGE: usize = 32;

fn photo() -> Vec<f32> {
    (0..W * H)
        .flat_map(|i| {
            if i % W < EDGE {
                [0.2, 0.25, 0.3]
            } else {
                [0.8, 0.7, 0.6]
            }
        })
        .collect()
}

/// Near (1.0) on the left, far (0.5) on the right, with a ramp over x = 31..39.
fn smeared() -> Vec<f32> {
    (0..W * H)
        .map(|i| {
            let t = (((i % W) as f32 - 31.0) / 8.0).clamp(0.0, 1.0);
            1.0 - 0.5 * t
        })
        .collect()
}

fn ideal(x: usize) -> f32 {
    if x < EDGE {
        1.0
    } else {
        0.5
    }
}

fn mean_error(d: &[f32]) -> f32 {
    d.iter()
        .enumerate()
        .map(|(i, v)| (v - ideal(i % W)).abs())
        .sum::<f32>()
        / d.len() as f32
}

#[test]
fn depth_edge_moves_onto_the_photo_edge() {
    let input = smeared();
    let opts = RefineOptions {
        radius: 16,
        ..RefineOptions::default()
    };
    let out = refine_disparity(&photo(), &input, W, H, opts);
    let before = mean_error(&input);
    let after = mean_error(&out);
    eprintln!("mean |error| against the ideal step: before {before:.4}, after {after:.4}");
    assert!(before > 0.02);
    for y in [0, H / 2, H - 1] {
        let row = &out[y * W..(y + 1) * W];
        for (x, &v) in row.iter().enumerate() {
            assert_eq!(v, ideal(x), "row {y}, x {x}: {v} (row {row:?})");
        }
    }
}

#[test]
fn a_window_narrower_than_the_ramp_still_improves_it() {
    let input = smeared();
    let opts = RefineOptions {
        radius: 4,
        ..RefineOptions::default()
    };
    let out = refine_disparity(&photo(), &input, W, H, opts);
    let row = &out[H / 2 * W..(H / 2 + 1) * W];
    // The largest single-pixel change is now at the photo's edge.
    let (at, _) = row
        .windows(2)
        .enumerate()
        .map(|(x, w)| (x + 1, (w[1] - w[0]).abs()))
        .fold((0, 0.0), |best, c| if c.1 > best.1 { c } else { best });
    assert_eq!(at, EDGE, "{row:?}");
    // Beyond the window the ramp stays (the median of a ramp is the ramp): only better.
    assert!(mean_error(&out) < mean_error(&input));
}

#[test]
fn flat_regions_and_texture_without_depth_change_stay_put() {
    // Texture (a checker) on a constant depth: the median of a constant is the constant.
    let rgb: Vec<f32> = (0..W * H)
        .flat_map(|i| {
            let v = if (i % W / 2 + i / W / 2) % 2 == 0 {
                0.1
            } else {
                0.9
            };
            [v, v, v]
        })
        .collect();
    let depth = vec![0.7f32; W * H];
    let out = refine_disparity(
        &rgb,
        &depth,
        W,
        H,
        RefineOptions {
            radius: 6,
            ..RefineOptions::default()
        },
    );
    assert!(out.iter().all(|&v| v == 0.7));
}
