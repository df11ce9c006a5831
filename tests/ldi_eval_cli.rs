//! `reshader eval-relocation` on a tiny dataset written here in the dataset renderer's
//! layout: a red box at depth 1 in front of a striped wall at depth 4, with novel views
//! ray-cast exactly, so the relocators must beat the unmoved input by a wide margin.

use std::path::Path;
use std::process::Command;

const W: u32 = 48;
const H: u32 = 32;
const F: f64 = 40.0;
/// Half-extent of the box in scene units (x, y), centred on the optical axis at depth 1.
const BOX: f64 = 0.2;
/// The tone mapping the command applies by default (×5.5, gamma 2.2) maps these
/// linear values into (0, 1).
const RED: [f32; 3] = [0.15, 0.005, 0.005];

fn wall(x: f64) -> [f32; 3] {
    // Stripes 0.25 units wide on the wall plane.
    if (x / 0.25).floor() as i64 % 2 == 0 {
        [0.01, 0.05, 0.12]
    } else {
        [0.01, 0.12, 0.05]
    }
}

/// Colour and depth along the ray of pixel (u, v) from a camera at `t` with the input
/// camera's orientation and intrinsics (pixel centres at integers, as the renderer has it).
fn trace(u: f64, v: f64, t: [f64; 3]) -> ([f32; 3], f32) {
    let (cx, cy) = (f64::from(W) / 2.0 - 0.5, f64::from(H) / 2.0 - 0.5);
    let d = [(u - cx) / F, (v - cy) / F];
    let at = |z: f64| [t[0] + d[0] * (z - t[2]), t[1] + d[1] * (z - t[2])];
    let p = at(1.0);
    if p[0].abs() < BOX && p[1].abs() < BOX {
        (RED, (1.0 - t[2]) as f32)
    } else {
        (wall(at(4.0)[0]), (4.0 - t[2]) as f32)
    }
}

fn save_exr(path: &Path, pixel: impl Fn(u32, u32) -> [f32; 3]) {
    let image = image::Rgb32FImage::from_fn(W, H, |x, y| image::Rgb(pixel(x, y)));
    image.save(path).unwrap();
}

fn write_example(dir: &Path, offset: [f64; 3]) {
    std::fs::create_dir_all(dir).unwrap();
    let input = |x: u32, y: u32| trace(f64::from(x), f64::from(y), [0.0; 3]);
    save_exr(&dir.join("input.exr"), |x, y| input(x, y).0);
    // "Reshaded": the input shaded a little brighter, as a view-dependent change would.
    save_exr(&dir.join("reshaded.exr"), |x, y| {
        input(x, y).0.map(|c| c * 1.1)
    });
    save_exr(&dir.join("novel.exr"), |x, y| {
        trace(f64::from(x), f64::from(y), offset).0.map(|c| c * 1.1)
    });
    save_exr(&dir.join("depth.exr"), |x, y| [input(x, y).1; 3]);
    image::GrayImage::from_pixel(W, H, image::Luma([255]))
        .save(dir.join("mask.png"))
        .unwrap();
    let meta = serde_json::json!({
        "width": W,
        "height": H,
        "input_camera": { "fx": F, "fy": F, "cx": f64::from(W) / 2.0 - 0.5, "cy": f64::from(H) / 2.0 - 0.5 },
        "novel_offset": offset,
    });
    std::fs::write(dir.join("meta.json"), meta.to_string()).unwrap();
}

fn mean_psnr(reports: &serde_json::Value, method: &str, colours: &str, region: &str) -> f64 {
    let examples = reports.as_array().unwrap();
    let sum: f64 = examples
        .iter()
        .map(|e| {
            e["scores"]
                .as_array()
                .unwrap()
                .iter()
                .find(|s| s["method"] == method && s["colours"] == colours)
                .unwrap()[region]["psnr"]
                .as_f64()
                .unwrap()
        })
        .sum();
    sum / examples.len() as f64
}

#[test]
fn eval_relocation_scores_the_relocators_and_writes_contact_sheets() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("val");
    write_example(&data.join("a"), [0.1, 0.0, 0.0]);
    write_example(&data.join("b"), [-0.08, 0.04, 0.05]);
    // Not an example: no meta.json.
    std::fs::create_dir_all(data.join("partial")).unwrap();
    let (sheets, json) = (dir.path().join("sheets"), dir.path().join("eval.json"));
    let out = Command::new(env!("CARGO_BIN_EXE_reshader"))
        .arg("eval-relocation")
        .arg(&data)
        .args(["--model", "none"])
        .arg("--sheets")
        .arg(&sheets)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.starts_with("2 examples"), "{stdout}");
    for row in [
        "| input | input |",
        "| mesh-warp | input |",
        "| ldi | reshaded",
    ] {
        assert!(stdout.contains(row), "{row} missing:\n{stdout}");
    }
    assert!(stdout.contains("LDI build"), "{stdout}");

    let reports: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(reports.as_array().unwrap().len(), 2);
    let input = mean_psnr(&reports, "input", "truth", "all");
    let ldi = mean_psnr(&reports, "ldi", "truth", "all");
    let mesh = mean_psnr(&reports, "mesh-warp", "truth", "all");
    assert!(ldi > input + 6.0, "ldi {ldi} dB vs input {input} dB");
    assert!(mesh > input + 3.0, "mesh {mesh} dB vs input {input} dB");
    // With the right colours the pixels the input sees are (nearly) exact.
    assert!(mean_psnr(&reports, "ldi", "truth", "visible") > 30.0);
    // The reshaded colours are the novel view's: relocating them beats relocating the input's.
    let alone = mean_psnr(&reports, "ldi", "input", "all");
    assert!(ldi > alone);
    // With --model none the network's colours are the input's: the same view, no gain.
    assert_eq!(mean_psnr(&reports, "ldi", "network", "all"), alone);
    assert!(
        stdout.contains("reshading model identity (no model)")
            && stdout.contains("| ldi | reshaded (network) |")
            && stdout.contains("LDI + network against LDI alone, valid pixels): +0.00 dB"),
        "{stdout}"
    );

    for id in ["a", "b"] {
        let sheet = image::open(sheets.join(format!("{id}.png"))).unwrap();
        assert_eq!((sheet.width(), sheet.height()), (4 * W, 2 * H));
    }
    assert!(!sheets.join("partial.png").exists());
}

#[test]
fn eval_relocation_names_a_folder_without_examples() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_reshader"))
        .env("RESHADER_MODEL", "none")
        .arg("eval-relocation")
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no complete examples") && stderr.contains(&*dir.path().to_string_lossy()),
        "{stderr}"
    );
}

/// The lobe-head fixture (random weights, so no claim about its gain) runs through the
/// same rows: what the runtime would show is scored, and a model that fails to load is
/// named before any example is read.
#[test]
fn eval_relocation_scores_a_reshading_model_and_refuses_a_missing_one() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("val");
    write_example(&data.join("a"), [0.1, 0.0, 0.0]);
    let json = dir.path().join("eval.json");
    let fixture = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/fixtures/reshade-fixture-fp32-lobes.json"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_reshader"))
        .arg("eval-relocation")
        .arg(&data)
        .args(["--model", fixture, "--json"])
        .arg(&json)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("reshading model") && stdout.contains("lobe"),
        "{stdout}"
    );
    let reports: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let network = mean_psnr(&reports, "ldi", "network", "all");
    assert!(network.is_finite() && network > 10.0, "{network}");

    let missing = dir.path().join("no-such-model.json");
    let out = Command::new(env!("CARGO_BIN_EXE_reshader"))
        .arg("eval-relocation")
        .arg(&data)
        .arg("--model")
        .arg(&missing)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no-such-model.json"), "{stderr}");
}

/// `--depth-source coarse` names its factor in the table's header; a factor under 1 is
/// refused before any example is read.
#[test]
fn eval_relocation_coarsens_by_the_factor_asked() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("val");
    write_example(&data.join("a"), [0.1, 0.0, 0.0]);
    let run = |factor: &str| {
        Command::new(env!("CARGO_BIN_EXE_reshader"))
            .arg("eval-relocation")
            .arg(&data)
            .args(["--model", "none", "--depth-source", "coarse"])
            .args(["--coarse-factor", factor])
            .output()
            .unwrap()
    };
    let out = run("1.6");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("Coarse (x1.6) depth"), "{stdout}");
    let out = run("0.5");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--coarse-factor") && stderr.contains("not a factor of 1 or more"),
        "{stderr}"
    );
}
