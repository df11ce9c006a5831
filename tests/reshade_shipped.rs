//! The shipped reshading models (models/reshade) on held-out rendered examples
//! (models/reshade/examples, written by `reshader-train examples` from the checkpoint the
//! models were exported from): the runtime must reproduce PyTorch's PSNR for the float
//! models, and every precision must bring most views closer to the ground truth than the
//! photo's own shading does.

use crate::reshade_support;

use std::path::{Path, PathBuf};

use reshade_support::{depth_from_disparity, read_npy, tract, ungated};
use reshader::engine::manifest::Precision;
use reshader::engine::{tract::TractEngine, Engine, ModelSource, Tensor};
use reshader::io::photo::SrgbImage;
use reshader::reshade::net::NetReshader;

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/reshade")
}

/// The one int8 encoder shipped (its name says PTQ or QAT, and the int8 form).
fn shipped_int8_encoder() -> PathBuf {
    let found: Vec<PathBuf> = std::fs::read_dir(shipped())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("reshade-lite-int8") && name.ends_with("-encoder.onnx")
        })
        .collect();
    assert_eq!(found.len(), 1, "int8 encoders shipped: {found:?}");
    found.into_iter().next().unwrap()
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
    let net = NetReshader::load(&shipped(), precision, tract(2), ungated()).unwrap();
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

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// The runtime's median gain over the photo's own shading, and PyTorch's (fp32).
fn median_gains(scores: &[(f64, f64, f64)]) -> (f64, f64) {
    (
        median(scores.iter().map(|(i, o, _)| o - i).collect()),
        median(scores.iter().map(|(i, _, p)| p - i).collect()),
    )
}

/// Most views closer to the truth than the photo's shading, and a positive median gain.
/// Not the mean: per-view gains are heavy-tailed (a view whose shading hardly changes can
/// lose 7 dB to a faint residual), so the mean of a few views is decided by one of them
/// (the model card has the means over 240 views).
fn assert_improves(scores: &[(f64, f64, f64)], what: &str) {
    let improved = scores.iter().filter(|(i, o, _)| o > i).count();
    let (ours, _) = median_gains(scores);
    let mean = scores.iter().map(|(i, o, _)| o - i).sum::<f64>() / scores.len() as f64;
    eprintln!(
        "{what}: {improved} of {} improved, median gain {ours:+.3} dB, mean {mean:+.3} dB",
        scores.len()
    );
    assert!(
        2 * improved > scores.len() && ours > 0.0,
        "{what}: {improved} of {} improved, median gain {ours:.3} dB: {scores:?}",
        scores.len()
    );
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
    assert_improves(&s, "fp32");
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
    assert_improves(&s, "fp16");
}

#[test]
fn int8_improves_the_views_as_fp32_does() {
    let s = scores(Precision::Int8);
    assert_improves(&s, "int8");
    // The quantisation issue's bar: int8 within 0.3 dB of fp32.
    let (int8, fp32) = median_gains(&s);
    assert!(
        (int8 - fp32).abs() < 0.3,
        "int8 median gain {int8:.3} dB, fp32 {fp32:.3} dB"
    );
}

#[test]
fn int8_weights_folded_at_load_compute_what_the_int8_graph_computes() {
    // The same bytes planned as int8 (tract gets f32 weights folded from the int8 ones)
    // and as fp32 (tract runs the graph's DequantizeLinear nodes itself) must agree.
    let path = shipped_int8_encoder();
    let bytes = std::fs::read(&path).unwrap();
    let (h, w) = (64, 96);
    let ramp = |n: usize, k: usize| -> Vec<f32> {
        (0..n).map(|i| ((i * k) % 251) as f32 / 250.0).collect()
    };
    let image = Tensor::new(vec![1, 3, h, w], ramp(3 * h * w, 7));
    let disparity = Tensor::new(vec![1, 1, h, w], ramp(h * w, 13));
    let shapes = [
        ("image", image.shape.clone()),
        ("disparity", disparity.shape.clone()),
    ];
    let outputs = ["bottleneck", "skip0", "skip1", "skip2", "skip3", "skip4"];
    let engine = TractEngine::new(1);
    let run = |precision| {
        let source = ModelSource {
            path: &path,
            bytes: &bytes,
            precision,
        };
        let plan = engine.plan(source, &shapes, &outputs).unwrap();
        plan.run(&[("image", &image), ("disparity", &disparity)])
            .unwrap()
    };
    let (folded, graph) = (run(Precision::Int8), run(Precision::Fp32));
    for ((a, b), name) in folded.iter().zip(&graph).zip(outputs) {
        assert_eq!(a.shape, b.shape, "{name}");
        let scale = b.data.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        let diff = a
            .data
            .iter()
            .zip(&b.data)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            diff <= 1e-4 * scale,
            "{name}: max difference {diff} at scale {scale}"
        );
    }
}

#[test]
fn the_input_camera_keeps_the_photo() {
    // A view from the photo's own camera must be the photo. The shipped 0.9.0 model's
    // zero-offset residual stays under four 8-bit levels on the 16 held-out examples
    // (measured: at most 0.90 levels; 0.8.0: 0.97, 0.7.0: 1.39, 0.6.0: 1.52, 0.5.0: 1.09).
    let net = NetReshader::load(&shipped(), Precision::Fp32, tract(2), ungated()).unwrap();
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
        eprintln!(
            "{}: at most {:.2} levels from the photo",
            e.name,
            worst * 255.0
        );
        assert!(worst < 4.0 / 255.0, "{}: {worst}", e.name);
    }
}
