//! Depth for the evaluation from the shipped depth network instead of the renderer, as
//! `render` would estimate it (fp32 model, edge refinement on), then scale-aligned to
//! the true depth: relative depth has an unknown scale and shift in disparity, and the
//! evaluation measures edges and uncovered regions, not the scale.

use std::path::Path;

use crate::depth::net::{
    network_depth, photo_size, refined, DepthNet, DepthNetError, NetChoice, StageOptions,
};
use crate::depth::refine::RefineOptions;
use crate::depth::DepthMap;
use crate::engine::manifest::Precision;
use crate::engine::resample;
use crate::io::photo::SrgbImage;

use super::SKY_DEPTH;

/// Where the evaluated methods take their depth from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EvalDepth {
    /// The renderer's depth.exr.
    #[default]
    Truth,
    /// The shipped depth network on input.exr (tone-mapped), aligned to depth.exr.
    Network,
    /// The renderer's depth with a network's edges ([`coarsened`]): the scene's shapes
    /// stay right, so what the edges cost is told apart from what the network's shapes
    /// cost.
    Coarse,
}

impl crate::io::keyword::Keyword for EvalDepth {
    const ALL: &'static [(Self, &'static str)] = &[
        (Self::Truth, "truth"),
        (Self::Network, "network"),
        (Self::Coarse, "coarse"),
    ];
}

/// How much coarser than the photo [`coarsened`] makes the depth by default: a 384-px
/// network output serving a photo of about a thousand pixels. `render` works at the
/// views' size, where a 384-px output is about 1.5-2 times coarser.
pub const COARSE_FACTOR: f64 = 3.0;

/// `truth` as a network would give it at `1/factor` of the photo's size: its disparity
/// area-shrunk, then grown back (ramps across every edge) and refined against the photo
/// by the stage that does it to network depth in `render`.
pub fn coarsened(photo: &SrgbImage, truth: &DepthMap, factor: f64) -> DepthMap {
    let (w, h) = (truth.width(), truth.height());
    let shrunk = |n: usize| ((n as f64 / factor) as usize).clamp(1, n);
    let (sw, sh) = (shrunk(w), shrunk(h));
    let disparity: Vec<f32> = truth.data().iter().map(|&z| 1.0 / z).collect();
    let small = resample::resize(&disparity, w, h, sw, sh);
    let (grown, _) = refined(
        &small,
        (sw, sh),
        &photo.to_rgb8(),
        (w, h),
        RefineOptions::default(),
    );
    DepthMap::new(w, h, grown.iter().map(|&d| 1.0 / d).collect())
}

/// `model` (its manifest or the .onnx beside it), else the shipped fp32 network, with
/// `render`'s engine (tract, every core).
pub fn load(model: Option<&Path>) -> Result<DepthNet, DepthNetError> {
    NetChoice {
        model: model.map(Path::to_path_buf),
        precision: Precision::Fp32,
        engine: "tract".into(),
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
    }
    .load()
}

/// The network's depth for `photo`, aligned to `truth` over the `valid` pixels.
pub fn estimate(
    net: &DepthNet,
    photo: &SrgbImage,
    truth: &DepthMap,
    valid: &[bool],
) -> Result<DepthMap, DepthNetError> {
    let rgb = photo.to_rgb8();
    let (estimated, _) = network_depth(net, &rgb, photo_size(&rgb), &StageOptions::default())?;
    Ok(aligned(&estimated, truth, valid))
}

/// `estimated` with its disparity mapped by the affine function that fits `truth`'s
/// disparity best in least squares over `valid` pixels (all pixels when none is valid).
pub fn aligned(estimated: &DepthMap, truth: &DepthMap, valid: &[bool]) -> DepthMap {
    let any = valid.iter().any(|&v| v);
    let pairs = || {
        estimated
            .data()
            .iter()
            .zip(truth.data())
            .zip(valid)
            .filter(move |(_, &v)| v || !any)
            .map(|((&e, &t), _)| (1.0 / f64::from(e), 1.0 / f64::from(t)))
    };
    let n = pairs().count().max(1) as f64;
    let (mx, my) = pairs().fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = pairs().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    let scale = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let shift = my - scale * mx;
    let floor = 1.0 / f64::from(SKY_DEPTH);
    let data = estimated
        .data()
        .iter()
        .map(|&e| (1.0 / (scale / f64::from(e) + shift).max(floor)) as f32)
        .collect();
    DepthMap::new(estimated.width(), estimated.height(), data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_affine_disparity_is_undone() {
        let truth: Vec<f32> = [1.0f32, 2.0, 4.0, 8.0].to_vec();
        // Disparity 3·d + 0.2 of the truth's.
        let estimated: Vec<f32> = truth.iter().map(|&z| 1.0 / (3.0 / z + 0.2)).collect();
        let out = aligned(
            &DepthMap::new(4, 1, estimated),
            &DepthMap::new(4, 1, truth.clone()),
            &[true; 4],
        );
        for (a, b) in out.data().iter().zip(&truth) {
            assert!((a - b).abs() < 1e-4 * b, "{a} vs {b}");
        }
    }

    #[test]
    fn coarsened_depth_keeps_the_plateaus_and_softens_the_edge() {
        // A near box (depth 1) in columns 20-39 before a wall (depth 2), 60x30; the
        // photo is one grey, so the refinement has no colour edge to put the step on.
        let (w, h) = (60, 30);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                if (20..40).contains(&(i % w)) {
                    1.0
                } else {
                    2.0
                }
            })
            .collect();
        let mut photo = SrgbImage::new(w as u32, h as u32);
        for y in 0..h as u32 {
            for x in 0..w as u32 {
                photo.put(x, y, [0.5; 3]);
            }
        }
        let out = coarsened(&photo, &DepthMap::new(w, h, depth.clone()), COARSE_FACTOR);
        let row = &out.data()[15 * w..16 * w];
        for (x, &z) in row.iter().enumerate() {
            assert!((1.0 - 1e-4..=2.0 + 1e-4).contains(&z), "{x}: {z}");
        }
        assert!((row[5] - 2.0).abs() < 1e-4 && (row[30] - 1.0).abs() < 1e-4);
        let between = row.iter().filter(|&&z| (1.01..1.99).contains(&z)).count();
        assert!(between >= 2, "the step is spread over a ramp: {row:?}");
    }

    #[test]
    fn invalid_pixels_do_not_pull_the_fit() {
        let truth = DepthMap::new(3, 1, vec![1.0, 2.0, 1.0]);
        let estimated = DepthMap::new(3, 1, vec![1.0, 2.0, 100.0]);
        let out = aligned(&estimated, &truth, &[true, true, false]);
        assert!((out.data()[0] - 1.0).abs() < 1e-5);
        assert!((out.data()[1] - 2.0).abs() < 1e-5);
    }
}
