//! Parity with the fixture's PyTorch reference (models/fixtures/parity.json): the
//! runtime, fed the closed-form photo and depth, must reproduce the network's output for
//! each precision and graph form, and return the photo at the input camera as the
//! fixture is known to (its manifest records ~6e-4 at camera 0).

use crate::reshade_support;

use reshade_support::{
    base64, f32s, fixture_dir, image_from_planar, manifest_path, max_abs_diff, tract, ungated,
};
use reshader::depth::DepthMap;
use reshader::engine::manifest::{Precision, Task};
use reshader::engine::Engine;
use reshader::io::photo::SrgbImage;
use reshader::reshade::net::{NetOptions, NetReshader};
use serde_json::Value;
use std::sync::Arc;

fn parity() -> Value {
    let text = std::fs::read_to_string(fixture_dir().join("parity.json")).unwrap();
    let p: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(p["format"], "reshader-parity/1");
    p
}

/// The parity inputs, built from the closed forms parity.json states.
fn inputs(p: &Value) -> (SrgbImage, DepthMap) {
    let (h, w) = (
        p["height"].as_u64().unwrap() as usize,
        p["width"].as_u64().unwrap() as usize,
    );
    let (hf, wf) = (h as f32, w as f32);
    let s = 0.15 * hf.min(wf);
    let mut planar = vec![0.0f32; 3 * h * w];
    let mut depth = vec![0.0f32; h * w];
    for y in 0..h {
        for x in 0..w {
            let (xf, yf) = (x as f32, y as f32);
            let blob =
                (-((xf - 0.4 * wf).powi(2) + (yf - 0.45 * hf).powi(2)) / (2.0 * s * s)).exp();
            for c in 0..3 {
                planar[(c * h + y) * w + x] = 0.1 + 0.1 * c as f32 + 0.2 * xf / wf + 0.5 * blob;
            }
            depth[y * w + x] = 1.5 + xf / wf + yf / hf;
        }
    }
    let sum: f64 = planar.iter().map(|&v| f64::from(v)).sum();
    let expected = p["input"]["image_sum"].as_f64().unwrap();
    assert!(
        (sum - expected).abs() < 1e-3 * expected,
        "image sum {sum} vs {expected}"
    );
    (
        image_from_planar(&[1, 3, h, w], &planar),
        DepthMap::new(w, h, depth),
    )
}

fn reference(p: &Value, case: &Value, key: &str) -> SrgbImage {
    let (h, w) = (
        p["height"].as_u64().unwrap() as usize,
        p["width"].as_u64().unwrap() as usize,
    );
    let data: Vec<f32> = f32s(&base64(case[key].as_str().unwrap()))
        .iter()
        .map(|v| v.clamp(0.0, 1.0))
        .collect();
    image_from_planar(&[1, 3, h, w], &data)
}

fn check(task: Task, precision: Precision, engine: Arc<dyn Engine>) {
    let p = parity();
    let spec = &p["precisions"][precision.to_string()];
    let key = spec["reference"].as_str().unwrap();
    let tolerance = spec["tolerance"].as_f64().unwrap() as f32;
    let (image, depth) = inputs(&p);
    let net = NetReshader::load(
        &manifest_path(task, precision),
        precision,
        engine,
        ungated(),
    )
    .unwrap();
    let prepared = net.prepare_photo(&image, &depth).unwrap();
    for case in p["cases"].as_array().unwrap() {
        let camera: Vec<f64> = case["camera"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let out = prepared
            .reshade_views(&[[camera[0], camera[1], camera[2]]])
            .unwrap()
            .remove(0);
        let d = max_abs_diff(&out, &reference(&p, case, key));
        assert!(
            d <= tolerance,
            "{task} {precision} camera {camera:?}: {d} > {tolerance}"
        );
    }
}

#[test]
fn fp32_single_graph_matches_pytorch() {
    check(Task::Reshade, Precision::Fp32, tract(1));
}

#[test]
fn fp32_encoder_decoder_matches_pytorch() {
    check(Task::ReshadeEncoder, Precision::Fp32, tract(2));
}

#[test]
fn fp16_matches_pytorch_within_its_tolerance() {
    check(Task::ReshadeEncoder, Precision::Fp16, tract(1));
    check(Task::Reshade, Precision::Fp16, tract(1));
}

#[test]
fn int8_matches_the_fake_quantised_network() {
    check(Task::ReshadeEncoder, Precision::Int8, tract(1));
    check(Task::Reshade, Precision::Int8, tract(1));
}

#[test]
fn the_input_camera_returns_the_photo() {
    let p = parity();
    let known = p["camera_dependence"]["identity_max_abs_at_camera_0"]
        .as_f64()
        .unwrap() as f32;
    let (image, depth) = inputs(&p);
    let path = manifest_path(Task::ReshadeEncoder, Precision::Fp32);
    let net = NetReshader::load(&path, Precision::Fp32, tract(1), ungated()).unwrap();
    let out = net
        .prepare_photo(&image, &depth)
        .unwrap()
        .reshade_views(&[[0.0; 3]])
        .unwrap()
        .remove(0);
    let d = max_abs_diff(&out, &image);
    assert!(
        d <= known + 1e-5,
        "camera 0 changes the photo by {d} (fixture: {known})"
    );
    assert!(d < 2e-3, "camera 0 changes the photo by {d}");
}

#[cfg(feature = "ort")]
mod onnxruntime {
    use super::*;

    fn ort() -> Arc<dyn Engine> {
        reshader::engine::by_name("ort", 1)
            .expect("the ort feature's tests need ORT_DYLIB_PATH set to a libonnxruntime.so")
    }

    #[test]
    fn ort_matches_pytorch_for_every_precision_and_form() {
        for precision in [Precision::Fp32, Precision::Fp16, Precision::Int8] {
            check(Task::Reshade, precision, ort());
            check(Task::ReshadeEncoder, precision, ort());
        }
    }
}

// --- the lobe heads (models/fixtures/parity-lobes.json, models/fixtures/{slide,photo}/…) --

mod lobes {
    use super::*;
    use reshade_support::manifest_path_in;
    use reshader::engine::manifest::{LobeDomain, LobeSpec};
    use reshader::reshade::net::lobes::{pixel_rays, LobeField, LobeReshader};
    use reshader::views::Intrinsics;
    use std::path::PathBuf;

    /// The brief's bound for the runtime against PyTorch: one 8-bit level per pixel.
    const ONE_LEVEL: f32 = 1.0 / 255.0;

    /// The fixtures of the lobe heads: `lobes` beside the residual one, `lobes-slide` and
    /// `lobes` in the linear-clamped domain with amplitudes from the photo in folders of
    /// their own (one lobe-head manifest per precision and folder).
    fn fixtures() -> [PathBuf; 3] {
        [
            fixture_dir(),
            fixture_dir().join("slide"),
            fixture_dir().join("photo"),
        ]
    }

    fn parity(dir: &std::path::Path) -> Value {
        let text = std::fs::read_to_string(dir.join("parity-lobes.json")).unwrap();
        let p: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(p["format"], "reshader-lobe-parity/1");
        p
    }

    fn spec(p: &Value) -> LobeSpec {
        LobeSpec {
            lobes: p["lobes"].as_u64().unwrap() as usize,
            deadzone: p["deadzone"].as_f64().unwrap() as f32,
            slide: p["head"].as_str().unwrap_or("lobes") == "lobes-slide",
            domain: LobeDomain::named(p["domain"].as_str().unwrap_or("display"))
                .expect("a domain the runtime has"),
        }
    }

    /// The camera the fixture's rays were made with, as the pipeline describes a photo's:
    /// its horizontal field of view, the principal point at the centre.
    fn camera(p: &Value) -> Intrinsics {
        let (h, w) = (
            p["height"].as_u64().unwrap() as u32,
            p["width"].as_u64().unwrap() as u32,
        );
        let c = Intrinsics::from_hfov(w, h, p["camera"]["hfov_deg"].as_f64().unwrap());
        let fx = p["camera"]["fx"].as_f64().unwrap();
        assert!((c.fx - fx).abs() < 1e-9 * fx, "{} vs {fx}", c.fx);
        // The fixture's principal point is OpenCV's (pixel centres at integers).
        assert_eq!(c.cx - 0.5, p["camera"]["cx"].as_f64().unwrap());
        assert_eq!(c.cy - 0.5, p["camera"]["cy"].as_f64().unwrap());
        c
    }

    fn cases(p: &Value) -> Vec<([f64; 3], &Value)> {
        p["cases"]
            .as_array()
            .unwrap()
            .iter()
            .map(|case| {
                let c: Vec<f64> = case["camera"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                ([c[0], c[1], c[2]], case)
            })
            .collect()
    }

    fn check(dir: &std::path::Path, precision: Precision, threads: usize) {
        let p = parity(dir);
        let spec = &p["precisions"][precision.to_string()];
        let key = spec["reference"].as_str().unwrap();
        let tolerance = (spec["tolerance"].as_f64().unwrap() as f32).max(ONE_LEVEL);
        let (image, depth) = inputs(&p);
        let path = manifest_path_in(dir, Task::ReshadeLobes, precision);
        assert_eq!(
            path.file_name().unwrap().to_str().unwrap(),
            spec["model"].as_str().unwrap()
        );
        let net =
            LobeReshader::load(&path, precision, tract(threads), NetOptions::default()).unwrap();
        assert_eq!(net.spec(), self::spec(&p), "{}", path.display());
        let prepared = net.prepare_photo(&image, &depth, &camera(&p)).unwrap();
        let mut beyond = false;
        for (centre, case) in cases(&p) {
            let out = prepared.reshade_view(centre).unwrap();
            if centre == [0.0; 3] {
                assert_eq!(
                    out, image,
                    "{precision}: the input camera must give the photo"
                );
                continue;
            }
            let d = max_abs_diff(&out, &reference(&p, case, key));
            eprintln!(
                "{} {precision} camera {centre:?}: max |runtime - PyTorch| {d:.2e}",
                net.spec().head()
            );
            assert!(
                d <= tolerance,
                "{} {precision} camera {centre:?}: {d} > {tolerance}",
                dir.display()
            );
            // And the view really changes (the comparison is not between two photos).
            assert!(max_abs_diff(&out, &image) > 0.05, "{precision} {centre:?}");
            beyond |= centre.iter().map(|c| c * c).sum::<f64>().sqrt() > 0.3;
        }
        assert!(beyond, "a camera beyond the trained 0.3 offset is checked");
    }

    #[test]
    fn fp32_lobes_match_pytorch_within_one_level_and_the_input_camera_is_the_photo() {
        for dir in fixtures() {
            check(&dir, Precision::Fp32, 1);
            check(&dir, Precision::Fp32, 2);
        }
    }

    #[test]
    fn fp16_and_int8_lobes_match_their_references() {
        for dir in fixtures() {
            check(&dir, Precision::Fp16, 1);
            check(&dir, Precision::Int8, 2);
        }
    }

    #[test]
    fn the_closed_form_on_pytorch_s_lobes_is_pytorch_s_shading() {
        // No engine: the fixture's own lobes through the Rust closed form, so that any
        // difference is the formula's, not the network's.
        for dir in fixtures() {
            let p = parity(&dir);
            let (h, w) = (
                p["height"].as_u64().unwrap() as usize,
                p["width"].as_u64().unwrap() as usize,
            );
            let (image, depth) = inputs(&p);
            let lobes = f32s(&base64(p["lobes_fp32"].as_str().unwrap()));
            let disparity: Vec<f32> = depth
                .data()
                .iter()
                .map(|&z| reshader::reshade::net::disparity(z))
                .collect();
            let planar: Vec<f32> = (0..3)
                .flat_map(|c| image.data().chunks_exact(3).map(move |px| px[c]))
                .collect();
            let rays = pixel_rays(&camera(&p), w, h);
            let field = LobeField::new(spec(&p), w, h, &lobes, &planar, &disparity, &rays).unwrap();
            for (centre, case) in cases(&p) {
                let out = field.reshade(&image, centre, 2).unwrap();
                let d = max_abs_diff(&out, &reference(&p, case, "reshaded"));
                eprintln!(
                    "{}: closed form on PyTorch's fields, camera {centre:?}: {d:.2e}",
                    dir.display()
                );
                assert!(d <= 1e-5, "{} camera {centre:?}: {d}", dir.display());
            }
        }
    }
}
