//! The runtime refuses reshading models whose manifest does not match what it feeds them,
//! naming the field; one test per checked field, each on a copy of the fixture.

mod reshade_support;

use std::path::{Path, PathBuf};

use reshade_support::{fixture_dir, manifest_path, tract};
use reshader::manifest::{Precision, Task};
use reshader::reshade_net::{NetOptions, NetReshader};
use serde_json::{json, Value};

/// Copies the fp32 single-graph fixture into a temporary directory, applies `edit` to
/// its manifest and returns the load error's message.
fn refusal(edit: impl FnOnce(&mut Value)) -> String {
    refusal_for(Task::Reshade, Precision::Fp32, edit)
}

fn refusal_for(task: Task, precision: Precision, edit: impl FnOnce(&mut Value)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = copy_fixture(task, precision, dir.path());
    if task == Task::ReshadeDecoder {
        copy_fixture(Task::ReshadeEncoder, precision, dir.path());
    }
    let mut m: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut m);
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    match NetReshader::load(&path, precision, tract(1), NetOptions::default()) {
        Ok(_) => panic!("the edited manifest was accepted: {m}"),
        Err(e) => e.to_string(),
    }
}

fn copy_fixture(task: Task, precision: Precision, to: &Path) -> PathBuf {
    let src = manifest_path(task, precision);
    let m: Value = serde_json::from_str(&std::fs::read_to_string(&src).unwrap()).unwrap();
    let file = m["file"].as_str().unwrap();
    std::fs::copy(fixture_dir().join(file), to.join(file)).unwrap();
    let dst = to.join(src.file_name().unwrap());
    std::fs::copy(&src, &dst).unwrap();
    dst
}

fn assert_names(message: &str, field: &str) {
    assert!(
        message.contains(&format!("`{field}`")),
        "error does not name `{field}`: {message}"
    );
}

#[test]
fn the_unedited_fixture_loads() {
    let dir = tempfile::tempdir().unwrap();
    let path = copy_fixture(Task::Reshade, Precision::Fp32, dir.path());
    NetReshader::load(&path, Precision::Fp32, tract(1), NetOptions::default()).unwrap();
}

#[test]
fn format_version_is_checked() {
    assert_names(
        &refusal(|m| m["format"] = json!("reshader-manifest/2")),
        "format",
    );
}

#[test]
fn task_is_checked() {
    assert_names(&refusal(|m| m["task"] = json!("depth")), "task");
    let unknown = refusal(|m| m["task"] = json!("relight"));
    assert!(unknown.contains("relight"), "{unknown}");
}

#[test]
fn precision_must_be_the_requested_one() {
    assert_names(&refusal(|m| m["precision"] = json!("int8")), "precision");
}

#[test]
fn tensor_names_are_checked() {
    let msg = refusal(|m| m["inputs"][1]["name"] = json!("depth"));
    assert_names(&msg, "inputs");
    let msg = refusal(|m| m["outputs"][0]["name"] = json!("output"));
    assert_names(&msg, "outputs");
}

#[test]
fn tensor_types_layouts_and_shapes_are_checked() {
    assert_names(
        &refusal(|m| m["inputs"][0]["dtype"] = json!("float16")),
        "inputs[0].dtype",
    );
    assert_names(
        &refusal(|m| m["inputs"][0]["layout"] = json!("NHWC")),
        "inputs[0].layout",
    );
    let msg = refusal(|m| m["inputs"][0]["shape"][1] = json!(4));
    assert_names(&msg, "inputs[0].shape");
}

#[test]
fn image_normalisation_is_checked() {
    assert_names(
        &refusal(|m| m["image"]["color"] = json!("linear")),
        "image.color",
    );
    assert_names(
        &refusal(|m| m["image"]["range"] = json!([-1, 1])),
        "image.range",
    );
    assert_names(
        &refusal(|m| m["image"]["channel_order"] = json!("bgr")),
        "image.channel_order",
    );
    assert_names(
        &refusal(|m| m["image"]["mean"] = json!([0.5, 0.5, 0.5])),
        "image.mean",
    );
}

#[test]
fn disparity_encoding_is_checked() {
    let field = "disparity_encoding";
    let formula = refusal(|m| m[field]["formula"] = json!("1/depth"));
    assert_names(&formula, "disparity_encoding.formula");
    let freqs = refusal(|m| m[field]["frequencies"] = json!(6));
    assert_names(&freqs, "disparity_encoding.frequencies");
    assert_names(
        &refusal(|m| m[field]["pi"] = json!(true)),
        "disparity_encoding.pi",
    );
    let in_graph = refusal(|m| m[field]["in_graph"] = json!(false));
    assert_names(&in_graph, "disparity_encoding.in_graph");
    assert_names(&refusal(|m| m[field] = Value::Null), field);
}

#[test]
fn camera_convention_is_checked() {
    let msg = refusal(|m| m["camera"]["convention"] = json!("opengl"));
    assert_names(&msg, "camera.convention");
}

#[test]
fn size_multiple_is_checked() {
    assert_names(
        &refusal(|m| m["size_multiple"] = json!(24)),
        "size_multiple",
    );
}

#[test]
fn missing_fields_are_named() {
    let msg = refusal(|m| {
        m.as_object_mut().unwrap().remove("precision");
    });
    assert!(msg.contains("precision"), "{msg}");
}

#[test]
fn checksum_mismatch_is_refused() {
    let msg = refusal(|m| m["sha256"] = json!("00".repeat(32)));
    assert!(msg.contains("sha256"), "{msg}");
}

#[test]
fn a_truncated_model_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = copy_fixture(Task::Reshade, Precision::Fp32, dir.path());
    let m: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let onnx = dir.path().join(m["file"].as_str().unwrap());
    let bytes = std::fs::read(&onnx).unwrap();
    std::fs::write(&onnx, &bytes[..bytes.len() / 2]).unwrap();
    let msg = NetReshader::load(&path, Precision::Fp32, tract(1), NetOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        msg.contains("sha256") && msg.contains(onnx.to_str().unwrap()),
        "{msg}"
    );
}

#[test]
fn decoder_manifest_is_checked_too() {
    let msg = refusal_for(Task::ReshadeDecoder, Precision::Fp32, |m| {
        m["camera"]["convention"] = json!("opengl")
    });
    assert_names(&msg, "camera.convention");
}

#[test]
fn a_pair_from_different_exports_is_refused() {
    let msg = refusal_for(Task::ReshadeDecoder, Precision::Fp32, |m| {
        m["version"] = json!("9.9.9")
    });
    assert_names(&msg, "version");
}

#[test]
fn graph_names_must_match_the_manifest() {
    // An encoder manifest that vouches (with a correct checksum) for the decoder's graph.
    let dir = tempfile::tempdir().unwrap();
    let path = copy_fixture(Task::ReshadeEncoder, Precision::Fp32, dir.path());
    let decoder = copy_fixture(Task::ReshadeDecoder, Precision::Fp32, dir.path());
    let dm: Value = serde_json::from_str(&std::fs::read_to_string(&decoder).unwrap()).unwrap();
    let mut m: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    m["file"] = dm["file"].clone();
    m["sha256"] = dm["sha256"].clone();
    std::fs::write(&path, serde_json::to_string(&m).unwrap()).unwrap();
    let net = NetReshader::load(&path, Precision::Fp32, tract(1), NetOptions::default()).unwrap();
    let (image, depth) = reshade_support::scene(64, 32);
    let msg = net.prepare_photo(&image, &depth).err().unwrap().to_string();
    assert!(msg.contains("graph's inputs"), "{msg}");
}
