//! The runtime refuses reshading models whose manifest does not match what it feeds them,
//! naming the field; one test per checked field, each on a copy of the fixture.

use crate::reshade_support;

use std::path::{Path, PathBuf};

use reshade_support::{fixture_dir, manifest_path, tract};
use reshader::engine::manifest::{Precision, Task};
use reshader::reshade::net::{NetOptions, NetReshader};
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

// --- the lobe head: its manifest fields and how a model is chosen -----------------------------

mod lobes {
    use super::*;
    use reshader::io::keyword::Keyword;
    use reshader::reshade::net::choice::{Head, ReshadeConfig};
    use reshader::reshade::net::lobes::LobeReshader;
    use reshader::views::Intrinsics;

    /// The fp32 lobe fixture copied into `dir`, its manifest edited by `edit`.
    fn edited(dir: &Path, edit: impl FnOnce(&mut Value)) -> PathBuf {
        let path = copy_fixture(Task::ReshadeLobes, Precision::Fp32, dir);
        let mut m: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        edit(&mut m);
        std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
        path
    }

    fn lobe_refusal(edit: impl FnOnce(&mut Value)) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = edited(dir.path(), edit);
        match LobeReshader::load(&path, Precision::Fp32, tract(1), NetOptions::default()) {
            Ok(_) => panic!("the edited lobe manifest was accepted"),
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(path.to_str().unwrap()),
                    "names the file: {msg}"
                );
                msg
            }
        }
    }

    #[test]
    fn the_lobe_fields_are_checked() {
        assert_names(&lobe_refusal(|m| m["head"] = json!("residual")), "head");
        assert_names(&lobe_refusal(|m| m["domain"] = json!("linear")), "domain");
        // The clamped domain is the lobes head's alone.
        let slide = lobe_refusal(|m| {
            m["head"] = json!("lobes-slide");
            m["domain"] = json!("linear-clamped");
            m.as_object_mut().unwrap().remove("channels");
        });
        assert_names(&slide, "domain");
        assert!(slide.contains("not \"lobes-slide\""), "{slide}");
        assert_names(&lobe_refusal(|m| m["deadzone"] = json!(0.7)), "deadzone");
        assert_names(
            &lobe_refusal(|m| m["lobe_layout"][3] = json!("lambda")),
            "lobe_layout",
        );
        assert_names(&lobe_refusal(|m| m["lobes"] = json!(9)), "lobes");
        assert_names(
            &lobe_refusal(|m| m["inputs"][2]["shape"][1] = json!(2)),
            "inputs[2].shape",
        );
        assert_names(
            &lobe_refusal(|m| {
                m.as_object_mut().unwrap().remove("lobes");
            }),
            "lobes",
        );
    }

    #[test]
    fn a_lobe_count_that_disagrees_with_the_output_channels_is_refused() {
        // K = 3 with the output still listing 14 = 7·2 channels.
        let msg = lobe_refusal(|m| {
            m["lobes"] = json!(3);
            m.as_object_mut().unwrap().remove("channels");
        });
        assert_names(&msg, "outputs[0].shape");
        assert!(msg.contains("21"), "{msg}");
    }

    #[test]
    fn a_lobes_slide_manifest_needs_its_layer_s_channels() {
        // The 2-lobe graph's manifest claiming the sliding layer: its channel list lacks
        // the layer, and without the list the output's 14 channels are not 7·2 + 4.
        let msg = lobe_refusal(|m| m["head"] = json!("lobes-slide"));
        assert_names(&msg, "channels");
        assert!(msg.contains("fraction_r"), "{msg}");
        let msg = lobe_refusal(|m| {
            m["head"] = json!("lobes-slide");
            m.as_object_mut().unwrap().remove("channels");
        });
        assert_names(&msg, "outputs[0].shape");
        assert!(msg.contains("18") && msg.contains("lobes-slide"), "{msg}");
    }

    #[test]
    fn a_graph_with_other_channels_than_its_manifest_is_refused_at_run_time() {
        // A consistent manifest (K = 3, 21 channels) vouching for the 2-lobe graph.
        let dir = tempfile::tempdir().unwrap();
        let path = edited(dir.path(), |m| {
            m["lobes"] = json!(3);
            m.as_object_mut().unwrap().remove("channels");
            m["outputs"][0]["shape"][1] = json!(21);
        });
        let net =
            LobeReshader::load(&path, Precision::Fp32, tract(1), NetOptions::default()).unwrap();
        let (image, depth) = reshade_support::scene(64, 32);
        let camera = Intrinsics::from_hfov(64, 32, 60.0);
        let msg = net
            .prepare_photo(&image, &depth, &camera)
            .err()
            .unwrap()
            .to_string();
        assert!(
            msg.contains("reshade-fixture-fp32-lobes.onnx")
                && msg.contains(path.to_str().unwrap())
                && msg.contains("21")
                && msg.contains("14"),
            "{msg}"
        );
    }

    /// The reshading settings `--model`, `--precision` and `--head` ask for.
    fn args(flags: &[&str]) -> ReshadeConfig {
        let mut config = ReshadeConfig::default();
        for pair in flags.chunks(2) {
            match pair {
                ["--model", v] => config.model = Some(PathBuf::from(v)),
                ["--precision", v] => config.precision = Some(v.parse().unwrap()),
                ["--head", v] => config.head = Head::from_keyword(v),
                _ => panic!("not a reshading flag: {pair:?}"),
            }
        }
        config
    }

    fn description(extra: &[&str]) -> Result<String, String> {
        args(extra)
            .build()
            .map(|r| r.description())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn a_directory_with_both_heads_loads_the_residual_one_unless_lobes_are_asked_for() {
        let dir = fixture_dir();
        let d = dir.to_str().unwrap();
        let residual = description(&["--model", d, "--precision", "fp32"]).unwrap();
        assert!(residual.contains("head residual"), "{residual}");
        let lobes = description(&["--model", d, "--precision", "fp32", "--head", "lobes"]).unwrap();
        assert!(
            lobes.contains("head lobes")
                && lobes.contains("in the display domain")
                && lobes.contains("reshade-fixture-fp32-lobes"),
            "{lobes}"
        );
        // int8: the weights-only lobe graph, found by its manifest whatever its name.
        let int8 = description(&["--model", d, "--precision", "int8", "--head", "lobes"]).unwrap();
        assert!(int8.contains("reshade-fixture-int8-wo-lobes"), "{int8}");
        // A folder of linear-clamped lobes says so.
        let photo = fixture_dir().join("photo");
        let clamped = description(&["--model", photo.to_str().unwrap(), "--precision", "fp32"]);
        let clamped = clamped.unwrap();
        assert!(
            clamped.contains("in the linear-clamped domain")
                && clamped.contains("reshade-fixture-photo-fp32-lobes"),
            "{clamped}"
        );
    }

    #[test]
    fn a_manifest_decides_its_head_and_a_contradicting_head_is_refused() {
        let lobes = manifest_path(Task::ReshadeLobes, Precision::Fp16);
        let l = lobes.to_str().unwrap();
        let d = description(&["--model", l]).unwrap();
        assert!(d.contains("head lobes") && d.contains("(fp16"), "{d}");
        let msg = description(&["--model", l, "--head", "residual"]).unwrap_err();
        assert!(msg.contains(l) && msg.contains("--head residual"), "{msg}");
        let residual = manifest_path(Task::ReshadeEncoder, Precision::Fp32);
        let r = residual.to_str().unwrap();
        let msg = description(&["--model", r, "--head", "lobes"]).unwrap_err();
        assert!(msg.contains(r) && msg.contains("lobes"), "{msg}");
        // The residual loader itself refuses a lobe manifest, saying how to load it.
        let msg = NetReshader::load(&lobes, Precision::Fp16, tract(1), NetOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(msg.contains(l) && msg.contains("--head lobes"), "{msg}");
    }

    #[test]
    fn a_missing_precision_or_head_is_named_with_the_files_there_are() {
        let dir = tempfile::tempdir().unwrap();
        copy_fixture(Task::ReshadeLobes, Precision::Fp32, dir.path());
        copy_fixture(Task::ReshadeEncoder, Precision::Int8, dir.path());
        copy_fixture(Task::ReshadeDecoder, Precision::Int8, dir.path());
        let d = dir.path().to_str().unwrap();
        // No --head: both heads are there, so the residual one (int8 by default) loads.
        assert!(description(&["--model", d])
            .unwrap()
            .contains("head residual"));
        let msg = description(&["--model", d, "--head", "lobes"]).unwrap_err();
        for part in [
            d,
            "precision int8",
            "it has fp32 (--precision fp32)",
            "reshade-fixture-int8-encoder.json",
            "--head residual",
        ] {
            assert!(msg.contains(part), "{part:?} missing: {msg}");
        }
        let msg = description(&["--model", d, "--precision", "fp32"]).unwrap_err();
        for part in [
            d,
            "residual-head",
            "reshade-fixture-fp32-lobes.json",
            "--head lobes",
        ] {
            assert!(msg.contains(part), "{part:?} missing: {msg}");
        }
        // A directory of lobe models only: that head, without being asked.
        let only = tempfile::tempdir().unwrap();
        copy_fixture(Task::ReshadeLobes, Precision::Fp32, only.path());
        let o = only.path().to_str().unwrap();
        let d = description(&["--model", o, "--precision", "fp32"]).unwrap();
        assert!(d.contains("head lobes"), "{d}");
    }
}
