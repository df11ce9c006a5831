//! `reshader depth` end to end with a tiny fixture model: the written map has the photo's
//! size and the --near/--depth-budget range; asking for embedded depth a photo lacks is
//! a clean failure that writes nothing.

use std::path::Path;
use std::process::Command;

use image::RgbImage;

fn reshader(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_reshader"))
        .env("RESHADER_MODEL", "none")
        .args(args)
        .output()
        .expect("run reshader")
}

fn photo(dir: &Path) -> String {
    let path = dir.join("photo.png");
    RgbImage::from_fn(96, 48, |x, y| {
        image::Rgb([(x * 2) as u8, (y * 5) as u8, 128])
    })
    .save(&path)
    .unwrap();
    path.display().to_string()
}

#[test]
fn depth_command_writes_scene_depth_in_the_requested_range() {
    let dir = tempfile::tempdir().unwrap();
    let photo = photo(dir.path());
    let out = dir.path().join("depth.npy");
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/depth/fixture-logdisp.json");
    let result = reshader(&[
        "depth",
        &photo,
        "--out",
        out.to_str().unwrap(),
        "--depth-model",
        model.to_str().unwrap(),
        "--near",
        "2",
        "--depth-budget",
        "3",
    ]);
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(
        stdout.contains("depth from network (fixture-logdisp"),
        "{stdout}"
    );
    let map = reshader::io::npy::parse(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!((map.cols, map.rows), (96, 48));
    // Clamping allows [near/2, 10 (near + budget)]; the percentiles sit at 2 and 5.
    let (lo, hi) = map
        .data
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(lo >= 1.0 && hi <= 50.0, "{lo}..{hi}");
    let mut sorted = map.data.clone();
    sorted.sort_by(f32::total_cmp);
    let p = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
    assert!(
        (p(0.02) - 2.0).abs() < 0.05 && (p(0.98) - 5.0).abs() < 0.1,
        "{} {}",
        p(0.02),
        p(0.98)
    );
}

#[test]
fn missing_embedded_depth_and_bad_options_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let photo = photo(dir.path());
    let out = dir.path().join("depth.npy");
    let out = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["--depth", "embedded"], "carries no embedded depth"),
        (vec!["--near", "-1"], "--near -1 must be a positive depth"),
        (
            vec!["--depth-model", "/nonexistent/model.onnx"],
            "has no manifest",
        ),
    ] {
        let mut all = vec!["depth", photo.as_str(), "--out", out];
        all.extend(args);
        let result = reshader(&all);
        let err = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(1), "{err}");
        assert!(err.contains(needle), "expected {needle:?} in: {err}");
        assert!(!Path::new(out).exists(), "{out} was written");
    }
}

/// Issue 26: errors read as words, not Rust Debug output ("LongestSide { size: 64,
/// multiple: 16 }").
#[test]
fn a_photo_the_depth_network_cannot_take_is_refused_in_words() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("strip.png");
    RgbImage::from_fn(400, 10, |x, _| image::Rgb([x as u8, 9, 9]))
        .save(&path)
        .unwrap();
    let out = dir.path().join("depth.npy");
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/depth/fixture-logdisp.json");
    let result = reshader(&[
        "depth",
        path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--depth-model",
        model.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(1), "{err}");
    assert!(
        err.contains("an input whose longest side is 64 px (sides multiples of 16)"),
        "{err}"
    );
    assert!(!err.contains('{') && !err.contains("LongestSide"), "{err}");
    assert!(!out.exists());
}
