//! Rendering with no depth file: the depth the photo carries, else the depth network, and
//! run.json says which (with the model file's sha256 and the stage's time). Bad depth
//! model options fail with a message naming the file, and nothing is written.

use crate::depth_support;
use crate::spine_support;

use std::path::{Path, PathBuf};

use serde_json::Value;
use spine_support::{entries, run, stderr, tiny_board};

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn fixture_model() -> String {
    repo("tests/fixtures/depth/fixture-logdisp.json")
        .display()
        .to_string()
}

fn run_json(out: &Path) -> Value {
    let bytes = std::fs::read(out.join("run.json")).expect("run.json written");
    serde_json::from_slice(&bytes).unwrap()
}

/// Renders for the tiny board into DIR/out and returns run.json.
fn render_ok(dir: &Path, photo: &str, extra: &[&str]) -> (Value, String) {
    let board = tiny_board();
    let out = dir.join("out");
    let out_s = out.display().to_string();
    let mut args = vec!["-v", "render", photo, "--board", &board, "--out", &out_s];
    args.extend_from_slice(extra);
    let result = run(&args);
    let err = stderr(&result);
    assert!(result.status.success(), "{err}");
    (run_json(&out), err)
}

#[test]
fn render_without_depth_runs_the_shipped_network() {
    let dir = tempfile::tempdir().unwrap();
    let photo = repo("examples/pumpkin/pumpkin.jpg").display().to_string();
    let (run, err) = render_ok(dir.path(), &photo, &[]);
    let out = dir.path().join("out");
    assert_eq!(
        entries(&out),
        [
            "panel.png",
            "preview.gif",
            "preview.html",
            "quilt_qs3x2a1.5.png",
            "rgbd.png",
            "run.json",
            "sbs.png",
            "views"
        ]
    );
    assert_eq!(entries(&out.join("views")).len(), 6);

    let depth = &run["inputs"]["depth"];
    assert_eq!(depth["source"], "network", "{depth}");
    assert!(
        depth["model"]
            .as_str()
            .unwrap()
            .starts_with("tiefenrausch-tuned-fp32"),
        "{depth}"
    );
    assert_eq!(depth["precision"], "fp32");
    let onnx = repo("models/depth/tiefenrausch-tuned-fp32.onnx");
    let sha = reshader::io::record::sha256_file(&onnx).unwrap();
    assert_eq!(depth["model_file"]["sha256"], sha.as_str());
    assert_eq!(depth["native_size"], serde_json::json!([288, 384]));
    // The robust ends of the pumpkin's disparity land at near = 1 and near + budget = 5.
    let range: Vec<f64> = serde_json::from_value(depth["depth_range"].clone()).unwrap();
    assert!(range[0] >= 0.5 && range[0] < 1.2, "{range:?}");
    assert!(range[1] > 4.0 && range[1] <= 50.0, "{range:?}");

    let timings = &run["timings_ms"];
    assert!(timings["depth"].as_f64().unwrap() > 0.0, "{timings}");
    assert!(timings["depth_model"].as_f64().is_some(), "{timings}");
    assert_eq!(
        err.matches("no reshading model").count(),
        usize::from(err.contains("no reshading model")),
        "the missing-model warning is given once: {err}"
    );
}

#[test]
fn depth_precision_and_scene_scale_reach_the_network() {
    let dir = tempfile::tempdir().unwrap();
    let photo = repo("examples/pumpkin/pumpkin.jpg").display().to_string();
    let (run, _) = render_ok(
        dir.path(),
        &photo,
        &[
            "--only",
            "panel",
            "--depth-precision",
            "int8",
            "--near",
            "2",
            "--depth-budget",
            "2",
            "--no-depth-refine",
        ],
    );
    let depth = &run["inputs"]["depth"];
    assert_eq!(depth["precision"], "int8", "{depth}");
    assert_eq!(
        depth["scene_scale"],
        serde_json::json!({"near": 2.0, "budget": 2.0})
    );
    assert_eq!(depth["refine"], Value::Null);
    let range: Vec<f64> = serde_json::from_value(depth["depth_range"].clone()).unwrap();
    assert!(range[0] >= 1.0 && range[1] <= 40.0, "{range:?}");
}

#[test]
fn embedded_depth_is_used_instead_of_the_network() {
    let dir = tempfile::tempdir().unwrap();
    let (png, _) = depth_support::depth_png(20, 15);
    let gdepth = dir.path().join("portrait.jpg");
    std::fs::write(
        &gdepth,
        depth_support::gdepth_jpeg(&depth_support::base64(&png), "RangeLinear", 700),
    )
    .unwrap();
    let gdepth = gdepth.display().to_string();
    // A model that does not exist: it must not even be loaded when the photo has depth.
    let missing = dir.path().join("unused.onnx").display().to_string();
    let (run, err) = render_ok(dir.path(), &gdepth, &["--depth-model", &missing]);
    let depth = &run["inputs"]["depth"];
    assert_eq!(depth["source"], "embedded", "{depth}");
    assert_eq!(depth["embedded"]["container"], "g-depth");
    assert_eq!(depth["embedded"]["format"], "RangeLinear");
    assert_eq!(depth["model"], Value::Null);
    assert_eq!(depth["native_size"], serde_json::json!([20, 15]));
    // Metric depth keeps its units: GDepth:Near 0.5 and Far 4.25.
    let range: Vec<f64> = serde_json::from_value(depth["depth_range"].clone()).unwrap();
    assert!(
        range[0] >= 0.5 - 1e-4 && range[1] <= 4.25 + 1e-3,
        "{range:?}"
    );
    assert!(
        err.contains("using the depth embedded in the photo"),
        "{err}"
    );
    assert!(run["timings_ms"]["depth"].as_f64().is_some());
    assert_eq!(run["timings_ms"]["depth_model"], Value::Null);

    let dd = dir.path().join("dynamic.jpg");
    std::fs::write(&dd, depth_support::dynamic_depth_jpeg(&png, png.len())).unwrap();
    let (run, _) = render_ok(dir.path(), &dd.display().to_string(), &["--only", "panel"]);
    assert_eq!(
        run["inputs"]["depth"]["embedded"]["container"],
        "dynamic-depth"
    );

    let (run, _) = render_ok(
        dir.path(),
        &gdepth,
        &["--depth", "network", "--depth-model", &fixture_model()],
    );
    let depth = &run["inputs"]["depth"];
    assert_eq!(depth["source"], "network", "{depth}");
    assert!(depth["model"]
        .as_str()
        .unwrap()
        .starts_with("fixture-logdisp"));
}

#[test]
fn unreadable_embedded_depth_falls_back_to_the_network_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let (png, _) = depth_support::depth_png(20, 15);
    let b64 = depth_support::base64(&png).replacen('A', "*", 1);
    let photo = dir.path().join("broken.jpg");
    std::fs::write(&photo, depth_support::gdepth_jpeg(&b64, "RangeLinear", 700)).unwrap();
    let (record, err) = render_ok(
        dir.path(),
        &photo.display().to_string(),
        &["--depth-model", &fixture_model(), "--only", "panel"],
    );
    let depth = &record["inputs"]["depth"];
    assert_eq!(depth["source"], "network", "{depth}");
    let why = depth["embedded_error"].as_str().unwrap();
    assert!(
        why.contains("broken.jpg") && why.contains("base64"),
        "{why}"
    );
    assert!(
        err.contains("estimating depth with the network instead"),
        "{err}"
    );

    let out = dir.path().join("strict").display().to_string();
    let board = tiny_board();
    let photo = photo.display().to_string();
    let strict = run(&[
        "render", &photo, "--depth", "embedded", "--board", &board, "--out", &out,
    ]);
    assert_eq!(strict.status.code(), Some(1));
    assert!(
        stderr(&strict).contains("broken.jpg"),
        "{}",
        stderr(&strict)
    );
    assert!(!Path::new(&out).exists());
}

#[test]
fn corrupt_photo_without_a_depth_file_fails_before_any_depth_work() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.jpg");
    std::fs::write(&bad, b"\xff\xd8\xff\xe0 not really a jpeg").unwrap();
    assert_failed_cleanly(dir.path(), &[], &bad.display().to_string(), &["bad.jpg"]);
}

#[test]
fn depth_file_is_recorded_with_its_sha256() {
    let dir = tempfile::tempdir().unwrap();
    let (photo, depth_file) = spine_support::write_scene(dir.path());
    let (run, _) = render_ok(dir.path(), &photo, &["--depth", &depth_file]);
    let depth = &run["inputs"]["depth"];
    assert_eq!(depth["source"], "file");
    assert_eq!(depth["kind"], "depth");
    let sha = reshader::io::record::sha256_file(Path::new(&depth_file)).unwrap();
    assert_eq!(depth["sha256"], sha.as_str());
    assert_eq!(run["timings_ms"]["depth"], Value::Null);
}

/// A failed render: exit 1, an error line naming `needles`, and `dir` holds only `keep`.
fn assert_failed_cleanly(dir: &Path, extra: &[&str], photo: &str, needles: &[&str]) {
    let before = entries(dir);
    let board = tiny_board();
    let out = dir.join("out").display().to_string();
    let mut args = vec!["render", photo, "--board", &board, "--out", &out];
    args.extend_from_slice(extra);
    let result = run(&args);
    let err = stderr(&result);
    assert_eq!(result.status.code(), Some(1), "{err}");
    assert!(err.lines().any(|l| l.starts_with("error: ")), "{err}");
    for needle in needles {
        assert!(err.contains(needle), "expected {needle:?} in: {err}");
    }
    assert_eq!(entries(dir), before, "a failed render left files behind");
}

#[test]
fn bad_depth_model_options_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (photo, _) = spine_support::write_scene(dir.path());

    let missing = dir.path().join("nowhere.onnx").display().to_string();
    assert_failed_cleanly(
        dir.path(),
        &["--depth-model", &missing],
        &photo,
        &["nowhere.onnx", "manifest"],
    );

    // A manifest whose sha256 does not match the model beside it.
    let fixtures = repo("tests/fixtures/depth");
    let onnx = dir.path().join("fixture-logdisp.onnx");
    std::fs::copy(fixtures.join("fixture-logdisp.onnx"), &onnx).unwrap();
    let manifest = std::fs::read_to_string(fixtures.join("fixture-logdisp.json")).unwrap();
    let mut manifest: Value = serde_json::from_str(&manifest).unwrap();
    manifest["sha256"] = "0".repeat(64).into();
    let manifest_path = dir.path().join("fixture-logdisp.json");
    std::fs::write(&manifest_path, manifest.to_string()).unwrap();
    assert_failed_cleanly(
        dir.path(),
        &["--depth-model", &onnx.display().to_string()],
        &photo,
        &["fixture-logdisp.onnx", "sha256"],
    );

    // A manifest for another task is refused by name.
    let sha = reshader::io::record::sha256_file(&onnx).unwrap();
    manifest["sha256"] = sha.into();
    manifest["task"] = "reshade".into();
    std::fs::write(&manifest_path, manifest.to_string()).unwrap();
    assert_failed_cleanly(
        dir.path(),
        &["--depth-model", &manifest_path.display().to_string()],
        &photo,
        &["fixture-logdisp.json"],
    );
}

#[test]
fn depth_options_that_contradict_each_other_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (photo, _) = spine_support::write_scene(dir.path());
    assert_failed_cleanly(
        dir.path(),
        &["--depth-kind", "disparity"],
        &photo,
        &["--depth-kind", "--depth FILE"],
    );
    assert_failed_cleanly(
        dir.path(),
        &["--depth", "embedded"],
        &photo,
        &["photo.png", "carries no embedded depth"],
    );
    assert_failed_cleanly(
        dir.path(),
        &["--depth-budget", "0"],
        &photo,
        &["--depth-budget 0"],
    );
}

#[test]
fn view_and_reshade_estimate_depth_too() {
    let dir = tempfile::tempdir().unwrap();
    let (photo, _) = spine_support::write_scene(dir.path());
    let model = fixture_model();
    for command in ["view", "reshade"] {
        let out = dir.path().join(format!("{command}.png"));
        let out_s = out.display().to_string();
        let result = run(&[
            command,
            &photo,
            "--depth-model",
            &model,
            "--camera",
            "0.1,0,0",
            "--out",
            &out_s,
        ]);
        assert!(result.status.success(), "{}", stderr(&result));
        let image = spine_support::load(&out);
        assert_eq!(
            image.dimensions(),
            (spine_support::PHOTO_W, spine_support::PHOTO_H)
        );
    }
}
