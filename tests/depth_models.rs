//! The depth-model contract, exercised with the tiny generated models in
//! tests/fixtures/depth (make_fixtures.py): one per output kind, each with a different
//! input policy, value range, channel order, normalisation and layout. Every output value
//! is a known 1x1 convolution of the normalised photo, so the test computes it by hand.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::RgbImage;
use reshader::depth::net::{
    self as depth_net, DepthNet, DepthNetError, OutputKind, SceneScale, StageOptions,
};
use reshader::engine::tract::TractEngine;
use serde_json::Value;

const WEIGHTS: [f32; 3] = [0.25, 0.5, 0.125];
const LEFT: [u8; 3] = [200, 100, 50];
const RIGHT: [u8; 3] = [20, 40, 240];

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/depth")
        .join(name)
}

fn load(path: &Path) -> Result<DepthNet, DepthNetError> {
    DepthNet::load(path, Arc::new(TractEngine::new(1)))
}

/// Left half one colour, right half another.
fn halves(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, _| {
        image::Rgb(if x < w / 2 { LEFT } else { RIGHT })
    })
}

fn conv(channels: [f32; 3]) -> f32 {
    channels.iter().zip(WEIGHTS).map(|(c, w)| c * w).sum()
}

/// Checks the pure-colour columns away from the boundary (resizing blends near it).
fn check_halves(values: &[f32], w: usize, h: usize, left: f32, right: f32) {
    for y in 0..h {
        for (x, want) in [
            (0, left),
            (w / 2 - 3, left),
            (w / 2 + 2, right),
            (w - 1, right),
        ] {
            let got = values[y * w + x];
            assert!(
                (got - want).abs() <= 1e-5 * want.abs().max(1.0),
                "({x},{y}): {got} vs {want}"
            );
        }
    }
}

#[test]
fn relative_disparity_model_with_mean_std_and_multiple_policy() {
    let net = load(&fixture("fixture-disparity.json")).unwrap();
    // 80x40, longer side capped at 64, sides rounded to multiples of 32: 64x32.
    let out = net.estimate(&halves(80, 40)).unwrap();
    assert_eq!(out.kind, OutputKind::Disparity);
    assert_eq!((out.map.width, out.map.height), (64, 32));
    let (mean, std) = ([0.5, 0.25, 0.0], [0.5, 0.25, 2.0]);
    let norm = |c: [u8; 3]| {
        conv(std::array::from_fn(|i| {
            (f32::from(c[i]) / 255.0 - mean[i]) / std[i]
        }))
    };
    check_halves(&out.map.values, 64, 32, norm(LEFT), norm(RIGHT));
}

#[test]
fn log_disparity_model_in_bgr_with_area_resize_is_exponentiated() {
    // Given as the .onnx file: the manifest of the same stem beside it is used.
    let net = load(&fixture("fixture-logdisp.onnx")).unwrap();
    // 96x48 -> longest side 64 -> 64x32 (multiples of 16), area-averaged.
    let out = net.estimate(&halves(96, 48)).unwrap();
    assert_eq!(out.kind, OutputKind::LogDisparity);
    assert_eq!((out.map.width, out.map.height), (64, 32));
    let bgr = |c: [u8; 3]| (conv([c[2], c[1], c[0]].map(|v| f32::from(v) / 255.0)) - 0.5).exp();
    check_halves(&out.map.values, 64, 32, bgr(LEFT), bgr(RIGHT));
}

#[test]
fn metric_depth_model_nhwc_0_255_fixed_size_at_half_resolution() {
    let net = load(&fixture("fixture-depth.json")).unwrap();
    let out = net.estimate(&halves(100, 50)).unwrap();
    assert_eq!(out.kind, OutputKind::Depth);
    // Fixed 48x32 input, 2x2 average pool in the graph: 24x16.
    assert_eq!((out.map.width, out.map.height), (24, 16));
    let depth = |c: [u8; 3]| 1.0 + 0.01 * conv(c.map(f32::from));
    check_halves(&out.map.values, 24, 16, depth(LEFT), depth(RIGHT));
    // Metric depth keeps its units through the stage; relative kinds get near/far.
    let opts = StageOptions::default();
    let (map, report) = depth_net::network_depth(&net, &halves(100, 50), [100, 50], &opts).unwrap();
    assert_eq!((map.width(), map.height()), (100, 50));
    // Asked for the views' smaller size, the stage refines and scales there: the same
    // depths, at that size.
    let (small, _) = depth_net::network_depth(&net, &halves(100, 50), [40, 20], &opts).unwrap();
    assert_eq!((small.width(), small.height()), (40, 20));
    assert!((small.at(0, 0) - depth(LEFT)).abs() < 1e-3);
    assert!((small.at(39, 19) - depth(RIGHT)).abs() < 1e-3);
    assert!(
        (map.at(0, 0) - depth(LEFT)).abs() < 1e-3,
        "{}",
        map.at(0, 0)
    );
    assert!(
        (map.at(99, 49) - depth(RIGHT)).abs() < 1e-3,
        "{}",
        map.at(99, 49)
    );
    assert!(report.scene_scale.is_none() && report.disparity_percentiles.is_none());
}

#[test]
fn relative_output_lands_between_near_and_far() {
    let net = load(&fixture("fixture-logdisp.json")).unwrap();
    let opts = StageOptions {
        scale: SceneScale {
            near: 2.0,
            budget: 3.0,
        },
        refine: None,
    };
    let (map, report) = depth_net::network_depth(&net, &halves(96, 48), [96, 48], &opts).unwrap();
    assert_eq!((map.width(), map.height()), (96, 48));
    // LEFT has the larger log-disparity: nearer, at `near`; RIGHT at near + budget.
    let bgr = |c: [u8; 3]| conv([c[2], c[1], c[0]].map(|v| f32::from(v) / 255.0));
    assert!(bgr(LEFT) > bgr(RIGHT));
    assert!((map.at(0, 0) - 2.0).abs() < 1e-4, "{}", map.at(0, 0));
    assert!((map.at(95, 0) - 5.0).abs() < 1e-3, "{}", map.at(95, 0));
    assert_eq!(report.source, "network");
    assert_eq!(report.native_size, [64, 32]);
}

/// Copies a fixture into `dir` with its manifest edited by `edit`.
fn edited(dir: &Path, name: &str, edit: impl Fn(&mut Value)) -> PathBuf {
    let onnx = format!("{name}.onnx");
    std::fs::copy(fixture(&onnx), dir.join(&onnx)).unwrap();
    let mut m: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture(&format!("{name}.json"))).unwrap())
            .unwrap();
    edit(&mut m);
    let path = dir.join(format!("{name}.json"));
    std::fs::write(&path, serde_json::to_string(&m).unwrap()).unwrap();
    path
}

/// A change that breaks the manifest, and the field the refusal must name.
type Violation = (Box<dyn Fn(&mut Value)>, &'static str);

#[test]
fn manifest_contract_violations_name_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases: Vec<Violation> = vec![
        (
            Box::new(|m| m["depth"]["output_kind"] = "inverse-depth".into()),
            "depth.output_kind",
        ),
        (
            Box::new(|m| m["depth"]["input_size"]["policy"] = "any".into()),
            "depth.input_size.policy",
        ),
        (
            Box::new(|m| m["depth"]["input_size"]["size"] = 0.into()),
            "depth.input_size.size",
        ),
        (Box::new(|m| m["depth"] = Value::Null), "`depth` is missing"),
        (
            Box::new(|m| m["task"] = "reshade".into()),
            "a depth model is needed",
        ),
        (
            Box::new(|m| m["image"]["mean"] = serde_json::json!([0.5, 0.5])),
            "image.mean",
        ),
        (
            Box::new(|m| m["image"]["channel_order"] = "rgba".into()),
            "image.channel_order",
        ),
        (
            Box::new(|m| m["image"]["range"] = serde_json::json!([-1, 1])),
            "image.range",
        ),
        (
            Box::new(|m| m["inputs"][0]["layout"] = "CHW".into()),
            "inputs[0].layout",
        ),
        (Box::new(|m| m["sha256"] = "00".repeat(32).into()), "sha256"),
        (
            Box::new(|m| m["outputs"][0]["name"] = "depth_out".into()),
            "depth_out",
        ),
    ];
    for (edit, needle) in cases {
        let path = edited(d, "fixture-disparity", edit);
        let err = match load(&path) {
            Ok(net) => net.estimate(&halves(64, 32)).map(|_| ()).unwrap_err(),
            Err(e) => e,
        };
        assert!(
            err.to_string().contains(needle),
            "expected {needle:?} in: {err}"
        );
    }
    let bare = d.join("bare.onnx");
    std::fs::copy(fixture("fixture-disparity.onnx"), &bare).unwrap();
    let err = load(&bare).err().expect("no manifest").to_string();
    assert!(
        err.contains("bare.json") && err.contains("manifest"),
        "{err}"
    );
}

/// Where tract spends the shipped depth network's time, per operator type, at the example
/// photo's network size (288×384), both precisions, as the runtime loads them (int8
/// weights folded, rewrites applied). The onnxruntime side of the same comparison is
/// `bench/profile_onnxruntime.py` (docs/benchmarks.md, "The depth network, operator by
/// operator"). Two threads, as the runtime runs it; `RESHADER_PROFILE_THREADS=1` shows
/// which operators the second thread speeds up.
#[test]
#[ignore = "measurement, not a check: run with --release --ignored --nocapture"]
fn profile_shipped_depth_network_in_tract() {
    let threads: usize = std::env::var("RESHADER_PROFILE_THREADS")
        .map(|v| {
            v.parse()
                .expect("RESHADER_PROFILE_THREADS: a number of threads")
        })
        .unwrap_or(2);
    let engine = TractEngine::new(threads);
    let input = reshader::engine::Tensor::new(
        vec![1, 3, 288, 384],
        (0..3 * 288 * 384)
            .map(|i| (i * 7919 % 1000) as f32 / 1000.0)
            .collect(),
    );
    for precision in ["fp32", "int8"] {
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("models/depth/tiefenrausch-{precision}.json"));
        let model = reshader::engine::manifest::load_verified(&manifest).unwrap();
        let source = reshader::engine::ModelSource {
            path: &model.model_path,
            bytes: &model.bytes,
            precision: model.manifest.precision,
        };
        let ops = engine
            .profile(source, &[("image", &input)], &["log_disparity"])
            .unwrap();
        let total: f64 = ops.iter().map(|(_, ms)| ms).sum();
        println!("\ntiefenrausch-{precision}, {threads} thread(s): {total:.1} ms\n\n| operator | ms | share |\n|---|---|---|");
        for (op, ms) in &ops {
            println!("| {op} | {ms:.1} | {:.0}% |", 100.0 * ms / total);
        }
    }
}
