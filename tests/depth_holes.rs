//! Depth files with holes (issue 22): a renderer's sky and a sensor's speckle, read with
//! `--depth-holes far` and `fill`, and the refusal that names the option by default.
//! `cargo test --test main depth::holes:: -- --nocapture` prints the fill's accuracy.

use crate::spine_support;

use std::path::Path;

use reshader::depth::holes::HolePolicy;
use reshader::depth::{DepthKind, DepthMap};
use reshader::io::photo::SrgbImage;
use spine_support::*;

const W: usize = 96;
const H: usize = 64;
/// The sky: the top rows of the map.
const SKY_ROWS: usize = 20;

/// A smooth scene: a floor and wall whose depth changes mostly across the image, and a
/// photo whose colours change smoothly with it (no edges to follow).
fn ground_truth() -> Vec<f32> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32 / W as f32, (i / W) as f32 / H as f32);
            2.0 + 2.5 * x + 0.3 * y + 0.4 * (3.0 * x).sin() * y
        })
        .collect()
}

fn photo() -> SrgbImage {
    let mut image = SrgbImage::new(W as u32, H as u32);
    for y in 0..H {
        for x in 0..W {
            let (u, v) = (x as f32 / W as f32, y as f32 / H as f32);
            image.put(x as u32, y as u32, [0.3 + 0.4 * u, 0.5 - 0.2 * v, 0.4]);
        }
    }
    image
}

/// Sky: every pixel of the top rows, written as NaN (what renderers write).
fn sky() -> Vec<bool> {
    (0..W * H).map(|i| i / W < SKY_ROWS).collect()
}

/// Sensor speckle: 5 % of the pixels, drawn at random (fixed seed), written as 0.
fn speckle() -> Vec<bool> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    (0..W * H)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % 100 < 5
        })
        .collect()
}

fn load(dir: &Path, holes: &[bool], hole_value: f32, policy: HolePolicy) -> (Vec<f32>, f64) {
    let values: Vec<f32> = ground_truth()
        .iter()
        .zip(holes)
        .map(|(&d, &h)| if h { hole_value } else { d })
        .collect();
    let path = dir.join("depth.npy");
    write_npy(&path, H, W, &values);
    let (map, report) = DepthMap::load(&path, DepthKind::Depth, policy, &photo()).unwrap();
    assert_eq!(report.hole_policy, policy);
    (map.data().to_vec(), report.hole_fraction)
}

/// Mean and largest relative error over the holes.
fn errors(filled: &[f32], holes: &[bool]) -> (f64, f64) {
    let truth = ground_truth();
    let rel: Vec<f64> = (0..filled.len())
        .filter(|&i| holes[i])
        .map(|i| f64::from((filled[i] - truth[i]).abs() / truth[i]))
        .collect();
    let mean = rel.iter().sum::<f64>() / rel.len() as f64;
    (mean, rel.iter().copied().fold(0.0, f64::max))
}

/// No hole is left and every value lies within the valid values' range.
fn assert_whole(filled: &[f32], holes: &[bool]) {
    let valid: Vec<f32> = ground_truth()
        .iter()
        .zip(holes)
        .filter(|(_, &h)| !h)
        .map(|(&d, _)| d)
        .collect();
    let lo = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = valid.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    for &v in filled {
        assert!(v.is_finite() && v > 0.0, "a hole remains: {v}");
        assert!(
            v >= lo * (1.0 - 1e-5) && v <= hi * (1.0 + 1e-5),
            "{v} outside the valid range {lo}..{hi}"
        );
    }
}

#[test]
fn far_puts_a_sky_and_speckle_at_the_farthest_depth() {
    let dir = tempfile::tempdir().unwrap();
    for (name, holes, value) in [("sky", sky(), f32::NAN), ("speckle", speckle(), 0.0)] {
        let (filled, fraction) = load(dir.path(), &holes, value, HolePolicy::Far);
        assert_whole(&filled, &holes);
        let count = holes.iter().filter(|&&h| h).count();
        assert!((fraction - count as f64 / (W * H) as f64).abs() < 1e-12);
        let farthest = ground_truth()
            .iter()
            .zip(&holes)
            .filter(|(_, &h)| !h)
            .map(|(&d, _)| d)
            .fold(f32::NEG_INFINITY, f32::max);
        for (i, &h) in holes.iter().enumerate() {
            if h {
                assert!((filled[i] - farthest).abs() < 1e-4, "{name}: {}", filled[i]);
            }
        }
    }
}

#[test]
fn fill_continues_a_smooth_scene_into_speckle_holes() {
    let dir = tempfile::tempdir().unwrap();
    let holes = speckle();
    let (filled, fraction) = load(dir.path(), &holes, 0.0, HolePolicy::Fill);
    assert!((0.04..0.06).contains(&fraction), "{fraction}");
    assert_whole(&filled, &holes);
    let (mean, max) = errors(&filled, &holes);
    println!("speckle fill: mean relative error {mean:.2e}, largest {max:.2e}");
    assert!(mean < 2e-3 && max < 1e-2, "mean {mean}, largest {max}");
}

#[test]
fn fill_extends_a_scene_under_a_sky() {
    let dir = tempfile::tempdir().unwrap();
    let holes = sky();
    let (filled, _) = load(dir.path(), &holes, f32::NAN, HolePolicy::Fill);
    assert_whole(&filled, &holes);
    let (mean, max) = errors(&filled, &holes);
    // Nothing under the sky tells how the scene goes on there; the reference is the
    // border row carried straight up.
    let truth = ground_truth();
    let carried: Vec<f32> = (0..W * H)
        .map(|i| truth[if holes[i] { SKY_ROWS * W + i % W } else { i }])
        .collect();
    let (carried_mean, carried_max) = errors(&carried, &holes);
    println!(
        "sky fill: mean relative error {mean:.2e}, largest {max:.2e} \
         (the border carried up: {carried_mean:.2e}, {carried_max:.2e})"
    );
    // At the image's left and right edges the fill leans on the one side it has, and
    // drifts: the largest errors are there.
    assert!(
        mean < 1.1 * carried_mean && max < 1.5 * carried_max,
        "mean {mean}, largest {max}"
    );
    // Continuous with the border: the sky's lowest row against the first valid one
    // (the scene's own step between rows is 0.5 %; the edge columns lean sideways).
    for x in 0..W {
        let (above, below) = (filled[(SKY_ROWS - 1) * W + x], filled[SKY_ROWS * W + x]);
        assert!(
            (above / below - 1.0).abs() < 0.02,
            "x={x}: {above} over {below}"
        );
    }
}

/// `render` with a depth file that has holes: refused by default with a message that
/// names --depth-holes, rendered with it, and the policy and hole share in run.json.
#[test]
fn render_refuses_holes_by_default_and_records_the_policy() {
    let tmp = tempfile::tempdir().unwrap();
    let (photo, _) = write_scene(tmp.path());
    let mut depth = scene_depth();
    for i in [5, 40, 41, 200] {
        depth[i] = 0.0;
    }
    let holed = tmp.path().join("holed.npy");
    write_npy(&holed, PHOTO_H as usize, PHOTO_W as usize, &depth);
    let (holed, board) = (holed.display().to_string(), tiny_board());
    let out = tmp.path().join("out");
    let out_s = out.display().to_string();
    let render = |extra: &[&str]| {
        let mut args = vec![
            "render", &photo, "--depth", &holed, "--board", &board, "--out", &out_s,
        ];
        args.extend_from_slice(extra);
        run(&args)
    };

    let refused = render(&[]);
    assert_eq!(refused.status.code(), Some(1));
    let err = stderr(&refused);
    for needle in [
        "holed.npy",
        "4 pixels without depth",
        "4 zero",
        "x=5, y=0",
        "--depth-holes fill",
    ] {
        assert!(err.contains(needle), "{needle:?} not in: {err}");
    }
    assert!(!out.exists(), "a refused run writes nothing");

    let filled = render(&["--depth-holes", "fill"]);
    assert!(filled.status.success(), "{}", stderr(&filled));
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap();
    let depth = &record["inputs"]["depth"];
    assert_eq!(depth["hole_policy"], "fill");
    let fraction = depth["hole_fraction"].as_f64().unwrap();
    assert!((fraction - 4.0 / 384.0).abs() < 1e-12, "{fraction}");

    let (scene_photo, _) = write_scene(tmp.path());
    let without_file = run(&[
        "render",
        &scene_photo,
        "--depth-holes",
        "far",
        "--board",
        &board,
        "--out",
        &out_s,
    ]);
    assert_eq!(without_file.status.code(), Some(1));
    assert!(
        stderr(&without_file).contains("give the file with --depth FILE"),
        "{}",
        stderr(&without_file)
    );
}
