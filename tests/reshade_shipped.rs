//! The shipped reshading models (models/reshade) on held-out rendered examples
//! (models/reshade/examples, written by `reshader-train examples` from the checkpoint the
//! models were exported from): the runtime must reproduce PyTorch's PSNR for the float
//! models, and every precision must bring the views closer to the ground truth than the
//! photo's own shading does.

mod reshade_support;

use std::path::{Path, PathBuf};

use reshade_support::{depth_from_disparity, read_npy, tract};
use reshader::manifest::Precision;
use reshader::photo::SrgbImage;
use reshader::reshade_net::{NetOptions, NetReshader};

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/reshade")
}

struct Example {
    name: String,
    photo: SrgbImage,
    truth: SrgbImage,
    valid: Vec<bool>,
    disparity: (Vec<usize>, Vec<f32>),
    camera: [f64; 3],
    psnr_input: f64,
    psnr_pytorch: f64,
}

fn examples() -> Vec<Example> {
    let dir = shipped().join("examples");
    let text = std::fs::read_to_string(dir.join("examples.json")).unwrap();
    let report: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rgb = |p: PathBuf| SrgbImage::from_rgb8(&image::open(p).unwrap().to_rgb8());
    report["examples"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            let name = e["example"].as_str().unwrap().to_owned();
            let at = dir.join(&name);
            let camera: Vec<f64> = serde_json::from_value(e["camera"].clone()).unwrap();
            let mask = image::open(at.join("mask.png")).unwrap().to_luma8();
            Example {
                photo: rgb(at.join("input.png")),
                truth: rgb(at.join("reshaded.png")),
                valid: mask.pixels().map(|p| p.0[0] > 127).collect(),
                disparity: read_npy(&at.join("disparity.npy")),
                camera: [camera[0], camera[1], camera[2]],
                psnr_input: e["psnr_input"].as_f64().unwrap(),
                psnr_pytorch: e["psnr_ours_pytorch"].as_f64().unwrap(),
                name,
            }
        })
        .collect()
}

/// PSNR over the valid pixels, as `reshader-train evaluate` measures it.
fn masked_psnr(a: &SrgbImage, b: &SrgbImage, valid: &[bool]) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for ((pa, pb), ok) in a.data().chunks(3).zip(b.data().chunks(3)).zip(valid) {
        if *ok {
            sum += pa
                .iter()
                .zip(pb)
                .map(|(x, y)| f64::from(x - y).powi(2))
                .sum::<f64>();
            n += 3;
        }
    }
    10.0 * (1.0 / (sum / n as f64).max(1e-12)).log10()
}

/// Per example: (PSNR of the photo, PSNR of the runtime's reshaded view, PyTorch's).
fn scores(precision: Precision) -> Vec<(f64, f64, f64)> {
    let net = NetReshader::load(&shipped(), precision, tract(2), NetOptions::default()).unwrap();
    examples()
        .into_iter()
        .map(|e| {
            let (shape, d) = &e.disparity;
            let depth = depth_from_disparity(shape[1], shape[0], d);
            let view = net
                .prepare_photo(&e.photo, &depth)
                .unwrap()
                .reshade_views(&[e.camera])
                .unwrap()
                .remove(0);
            let input = masked_psnr(&e.photo, &e.truth, &e.valid);
            assert!(
                (input - e.psnr_input).abs() < 1e-3,
                "{}: input PSNR {input} here, {} when written",
                e.name,
                e.psnr_input
            );
            (
                input,
                masked_psnr(&view, &e.truth, &e.valid),
                e.psnr_pytorch,
            )
        })
        .collect()
}

fn mean_gain(scores: &[(f64, f64, f64)]) -> f64 {
    scores.iter().map(|(i, o, _)| o - i).sum::<f64>() / scores.len() as f64
}

#[test]
fn fp32_reproduces_pytorch_and_improves_the_views() {
    let s = scores(Precision::Fp32);
    for (input, ours, pytorch) in &s {
        assert!(
            (ours - pytorch).abs() < 0.05,
            "tract {ours:.3} dB vs PyTorch {pytorch:.3} dB (input {input:.3})"
        );
    }
    assert!(mean_gain(&s) > 0.0, "{s:?}");
}

#[test]
fn fp16_stays_with_fp32() {
    let s = scores(Precision::Fp16);
    for (_, ours, pytorch) in &s {
        assert!(
            (ours - pytorch).abs() < 0.1,
            "fp16 {ours:.3} vs {pytorch:.3}"
        );
    }
    assert!(mean_gain(&s) > 0.0, "{s:?}");
}

#[test]
fn int8_improves_the_views() {
    let s = scores(Precision::Int8);
    assert!(mean_gain(&s) > 0.0, "{s:?}");
}

#[test]
fn the_input_camera_keeps_the_photo() {
    // A view from the photo's own camera must be the photo: the shipped model's zero-offset
    // residual stays under two 8-bit levels everywhere on the held-out examples (measured:
    // at most 1.4 levels).
    let net =
        NetReshader::load(&shipped(), Precision::Fp32, tract(2), NetOptions::default()).unwrap();
    for e in examples() {
        let (shape, d) = &e.disparity;
        let depth = depth_from_disparity(shape[1], shape[0], d);
        let view = net
            .prepare_photo(&e.photo, &depth)
            .unwrap()
            .reshade_views(&[[0.0; 3]])
            .unwrap()
            .remove(0);
        let worst = view
            .data()
            .iter()
            .zip(e.photo.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 2.0 / 255.0, "{}: {worst}", e.name);
    }
}
