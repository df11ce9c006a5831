//! Every bad input gives a non-zero exit, a message naming the file and the problem, and
//! leaves no output behind.

use crate::spine_support;

use std::path::Path;

use spine_support::*;

struct Case {
    dir: tempfile::TempDir,
    photo: String,
    depth: String,
}

impl Case {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let (photo, depth) = write_scene(dir.path());
        Self { dir, photo, depth }
    }

    fn path(&self, name: &str) -> String {
        self.dir.path().join(name).display().to_string()
    }

    fn out(&self) -> String {
        self.path("out")
    }

    fn render(&self, photo: &str, depth: &str, extra: &[&str]) -> std::process::Output {
        let board = tiny_board();
        let out = self.out();
        let mut args = vec![
            "render", photo, "--depth", depth, "--board", &board, "--out", &out,
        ];
        args.extend_from_slice(extra);
        run(&args)
    }

    /// `reshader view` of the case's photo and depth into `out`.
    fn view(&self, out: &str, extra: &[&str]) -> std::process::Output {
        let mut args = vec!["view", &self.photo, "--depth", &self.depth, "--out", out];
        args.extend_from_slice(extra);
        run(&args)
    }

    /// The run failed, said `needles` on stderr, and the directory holds only the inputs.
    fn assert_failed_cleanly(&self, result: &std::process::Output, needles: &[&str]) {
        let err = stderr(result);
        assert_eq!(result.status.code(), Some(1), "stderr: {err}");
        // Warnings (e.g. that no reshading model is installed) may come first.
        assert!(err.lines().any(|l| l.starts_with("error: ")), "{err}");
        for needle in needles {
            assert!(err.contains(needle), "expected {needle:?} in: {err}");
        }
        let inputs = ["bad", "depth.npy", "photo.png"];
        let left: Vec<String> = entries(self.dir.path())
            .into_iter()
            .filter(|name| !inputs.iter().any(|i| name.starts_with(i)))
            .collect();
        assert!(left.is_empty(), "left behind: {left:?}");
    }
}

#[test]
fn corrupt_photo() {
    let case = Case::new();
    let bad = case.path("bad.jpg");
    std::fs::write(&bad, b"\xff\xd8\xff\xe0 not really a jpeg").unwrap();
    let result = case.render(&bad, &case.depth, &[]);
    case.assert_failed_cleanly(&result, &["bad.jpg", "decode"]);
}

#[test]
fn missing_photo() {
    let case = Case::new();
    let missing = case.path("bad-missing.png");
    let result = case.render(&missing, &case.depth, &[]);
    case.assert_failed_cleanly(&result, &["bad-missing.png", "cannot read photo"]);
}

#[test]
fn depth_with_wrong_aspect() {
    let case = Case::new();
    let bad = case.path("bad-aspect.npy");
    let depth: Vec<f32> = (0..24 * 16).map(|i| 2.0 + (i % 16) as f32 * 0.1).collect();
    write_npy(Path::new(&bad), 24, 16, &depth);
    let result = case.render(&case.photo, &bad, &[]);
    case.assert_failed_cleanly(&result, &["bad-aspect.npy", "16x24", "24x16", "aspect"]);
}

#[test]
fn depth_of_other_size_but_same_aspect_is_resized() {
    let case = Case::new();
    let half = case.path("bad-half.npy");
    let depth: Vec<f32> = (0..12 * 8).map(|i| 2.0 + (i % 12) as f32 * 0.1).collect();
    write_npy(Path::new(&half), 8, 12, &depth);
    let board = tiny_board();
    let out = case.out();
    let result = run(&[
        "-v",
        "render",
        &case.photo,
        "--depth",
        &half,
        "--board",
        &board,
        "--out",
        &out,
        "--only",
        "panel",
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(stderr(&result).contains("resizing to the photo's 24x16"));
    let run: serde_json::Value =
        serde_json::from_slice(&std::fs::read(Path::new(&out).join("run.json")).unwrap()).unwrap();
    assert_eq!(
        run["inputs"]["depth"]["resized_to"],
        serde_json::json!([24, 16])
    );
}

#[test]
fn depth_with_nan() {
    let case = Case::new();
    let bad = case.path("bad-nan.npy");
    let mut depth = scene_depth();
    depth[5 * 24 + 3] = f32::NAN;
    write_npy(Path::new(&bad), 16, 24, &depth);
    let result = case.render(&case.photo, &bad, &[]);
    case.assert_failed_cleanly(&result, &["bad-nan.npy", "1 NaN", "x=3, y=5"]);
}

#[test]
fn constant_depth() {
    let case = Case::new();
    let bad = case.path("bad-flat.npy");
    write_npy(Path::new(&bad), 16, 24, &vec![3.0; 16 * 24]);
    let result = case.render(&case.photo, &bad, &["--depth-kind", "disparity"]);
    case.assert_failed_cleanly(&result, &["bad-flat.npy", "all values equal"]);
}

#[test]
fn negative_depth_suggests_disparity() {
    let case = Case::new();
    let bad = case.path("bad-neg.npy");
    let depth: Vec<f32> = scene_depth().iter().map(|d| d - 2.0).collect();
    write_npy(Path::new(&bad), 16, 24, &depth);
    let result = case.render(&case.photo, &bad, &[]);
    case.assert_failed_cleanly(&result, &["bad-neg.npy", "<= 0", "--depth-kind disparity"]);
}

#[test]
fn corrupt_npy_header() {
    let case = Case::new();
    let bad = case.path("bad-header.npy");
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    let header = b"{'descr': '<f4', 'fortran_order': False, 'shape': (16, 24), 'evil': 1}\n";
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header);
    let result = case.render(&case.photo, &bad_file(&bad, &bytes), &[]);
    case.assert_failed_cleanly(&result, &["bad-header.npy", "unknown key 'evil'"]);
}

fn bad_file(path: &str, bytes: &[u8]) -> String {
    std::fs::write(path, bytes).unwrap();
    path.into()
}

#[test]
fn unsupported_depth_type() {
    let case = Case::new();
    let bad = bad_file(&case.path("bad.txt"), b"1 2 3");
    let result = case.render(&case.photo, &bad, &[]);
    case.assert_failed_cleanly(&result, &["bad.txt", "unsupported file type"]);
}

#[test]
fn unknown_board_with_typo() {
    let case = Case::new();
    let out = case.out();
    let result = run(&[
        "render",
        &case.photo,
        "--depth",
        &case.depth,
        "--board",
        "looking-glass-portait",
        "--out",
        &out,
    ]);
    case.assert_failed_cleanly(
        &result,
        &["looking-glass-portait", "looking-glass-portrait"],
    );
}

#[test]
fn bad_calibration_file() {
    let case = Case::new();
    let bad = bad_file(
        &case.path("bad-visual.json"),
        b"{\"pitch\": {\"value\": 50}, ",
    );
    let result = case.render(&case.photo, &case.depth, &["--calibration", &bad]);
    case.assert_failed_cleanly(&result, &["bad-visual.json"]);
    let bad = bad_file(
        &case.path("bad-visual2.json"),
        b"{\"pitch\": {\"value\": -50}, \"slope\": {\"value\": -7}, \"center\": {\"value\": 0}}",
    );
    let result = case.render(&case.photo, &case.depth, &["--calibration", &bad]);
    case.assert_failed_cleanly(&result, &["bad-visual2.json", "pitch"]);
}

#[test]
fn sbs_pair_out_of_range() {
    let case = Case::new();
    let result = case.render(&case.photo, &case.depth, &["--sbs-pair", "0,6"]);
    case.assert_failed_cleanly(&result, &["--sbs-pair 0,6", "0..5"]);
}

#[test]
fn bad_fov_and_depthiness() {
    let case = Case::new();
    let result = case.render(&case.photo, &case.depth, &["--fov", "200"]);
    case.assert_failed_cleanly(&result, &["field of view 200"]);
    let result = case.render(&case.photo, &case.depth, &["--depthiness", "-1"]);
    case.assert_failed_cleanly(&result, &["--depthiness -1"]);
}

#[test]
fn failed_render_keeps_an_earlier_output_intact() {
    let case = Case::new();
    let ok = case.render(&case.photo, &case.depth, &["--only", "panel"]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let out = Path::new(&case.out()).to_path_buf();
    let before = std::fs::read(out.join("panel.png")).unwrap();
    let bad = bad_file(&case.path("bad.jpg"), b"garbage");
    let result = case.render(&bad, &case.depth, &[]);
    assert_eq!(result.status.code(), Some(1));
    assert_eq!(entries(&out), ["panel.png", "run.json"]);
    assert_eq!(std::fs::read(out.join("panel.png")).unwrap(), before);
}

#[test]
fn view_with_unknown_output_type() {
    let case = Case::new();
    let out = case.path("view.gif");
    let result = case.view(&out, &["--camera", "0.1,0,0"]);
    case.assert_failed_cleanly(&result, &["view.gif", ".png, .exr, .npy"]);
}

#[test]
fn view_with_camera_beyond_focus() {
    let case = Case::new();
    let out = case.path("view.png");
    let result = case.view(&out, &["--focus", "2", "--camera", "0,0,2.5"]);
    case.assert_failed_cleanly(&result, &["beyond the zero-parallax plane"]);
}

#[test]
fn malformed_camera_is_a_usage_error() {
    let case = Case::new();
    let out = case.path("view.png");
    let result = case.view(&out, &["--camera", "0.1,0"]);
    assert_eq!(result.status.code(), Some(2));
    assert!(stderr(&result).contains("TX,TY,TZ"));
}

#[test]
fn a_zero_network_size_is_a_usage_error() {
    let case = Case::new();
    let out = case.path("view.png");
    let result = case.view(&out, &["--reshade-size", "0"]);
    assert_eq!(result.status.code(), Some(2));
    assert!(stderr(&result).contains("neither `full` nor a size in pixels"));
    assert!(!Path::new(&out).exists());
}

#[test]
fn weave_with_missing_view() {
    let case = Case::new();
    let views = case.dir.path().join("bad-views");
    std::fs::create_dir(&views).unwrap();
    for i in [0, 1, 2, 3, 4, 6] {
        scene_photo()
            .save(views.join(format!("view_{i:02}.png")))
            .unwrap();
    }
    let out = case.path("panel.png");
    let board = tiny_board();
    let views_s = views.display().to_string();
    let result = run(&["weave", &views_s, "--board", &board, "--out", &out]);
    case.assert_failed_cleanly(&result, &["bad-views", "view_05.png is missing"]);
    std::fs::remove_file(views.join("view_06.png")).unwrap();
    let result = run(&["weave", &views_s, "--board", &board, "--out", &out]);
    case.assert_failed_cleanly(&result, &["found 5 view_NN.png files", "6 views"]);
}

#[test]
fn model_directory_without_the_default_int8_says_which_precisions_it_has() {
    let case = Case::new();
    let models = case.path("bad-models");
    std::fs::create_dir(&models).unwrap();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures");
    for half in ["encoder", "decoder"] {
        for ext in ["json", "onnx"] {
            let name = format!("reshade-fixture-fp32-{half}.{ext}");
            std::fs::copy(fixtures.join(&name), Path::new(&models).join(&name)).unwrap();
        }
    }
    let result = case.render(&case.photo, &case.depth, &["--model", &models]);
    case.assert_failed_cleanly(
        &result,
        &[
            "bad-models",
            "precision int8",
            "it has fp32 (--precision fp32)",
        ],
    );
}

/// Issue 26: a JPEG cut in half decoded with grey in its lower half and rendered with
/// exit 0; the decoder's silence is no longer trusted.
#[test]
fn truncated_jpeg_is_an_error_naming_the_photo() {
    let case = Case::new();
    // Large enough that half of it ends inside the image data, not in a header.
    let big = image::imageops::resize(
        &scene_photo(),
        PHOTO_W * 10,
        PHOTO_H * 10,
        image::imageops::FilterType::Nearest,
    );
    let mut jpeg = Vec::new();
    big.write_to(
        &mut std::io::Cursor::new(&mut jpeg),
        image::ImageFormat::Jpeg,
    )
    .unwrap();
    let half = bad_file(&case.path("bad-half.jpg"), &jpeg[..jpeg.len() / 2]);
    let result = case.render(&half, &case.depth, &[]);
    case.assert_failed_cleanly(&result, &["bad-half.jpg", "truncated"]);
}

/// Issue 26: absurd options panicked in the LDI renderer (index out of bounds, exit
/// 101); now they are refused with a message, and any depth scale renders.
#[test]
fn absurd_depthiness_and_cameras_are_refused() {
    let case = Case::new();
    let result = case.render(&case.photo, &case.depth, &["--depthiness", "1e5"]);
    case.assert_failed_cleanly(&result, &["--depthiness 100000", "from 0 to 10"]);
    let out = case.path("view.png");
    for camera in ["1e30,0,0", "0,-1e300,0", "0,0,-1e30"] {
        let result = case.view(&out, &["--camera", camera]);
        case.assert_failed_cleanly(&result, &["times the zero-parallax depth"]);
    }
}

#[test]
fn any_depth_scale_and_any_allowed_camera_render() {
    let case = Case::new();
    for scale in [1e7f32, 1e-7, 1e30, 1e-30] {
        let scaled = case.path(&format!("depth-{scale:e}.npy"));
        let data: Vec<f32> = scene_depth().iter().map(|d| d * scale).collect();
        write_npy(
            Path::new(&scaled),
            PHOTO_H as usize,
            PHOTO_W as usize,
            &data,
        );
        let result = case.render(&case.photo, &scaled, &["--only", "panel"]);
        assert_eq!(
            result.status.code(),
            Some(0),
            "depth x{scale:e}: {}",
            stderr(&result)
        );
        let result = case.render(
            &case.photo,
            &scaled,
            &["--only", "panel", "--depthiness", "10"],
        );
        assert_eq!(result.status.code(), Some(0), "{}", stderr(&result));
    }
    // Beyond what f32 resamples exactly: refused, naming the file and a value.
    let tiny = case.path("bad-tiny.npy");
    let data: Vec<f32> = scene_depth().iter().map(|d| d * 1e-36).collect();
    write_npy(Path::new(&tiny), PHOTO_H as usize, PHOTO_W as usize, &data);
    let result = case.render(&case.photo, &tiny, &["--only", "panel"]);
    assert_eq!(result.status.code(), Some(1), "{}", stderr(&result));
    assert!(
        stderr(&result).contains("bad-tiny.npy has 384 values outside 1e-32 to 1e32"),
        "{}",
        stderr(&result)
    );
    // Within the limit but far off to the side or behind: the view sees little or
    // nothing of the scene, and is still an image.
    for camera in ["5000,0,0", "0,0,-20000", "-3,2,1"] {
        let out = case.path("view.png");
        let result = case.view(&out, &["--camera", camera]);
        assert_eq!(
            result.status.code(),
            Some(0),
            "{camera}: {}",
            stderr(&result)
        );
        assert_eq!(load(Path::new(&out)).dimensions(), (PHOTO_W, PHOTO_H));
    }
}

/// Issue 26: a misspelt key and absurd values in a visual.json passed silently.
#[test]
fn calibration_with_a_misspelt_key_or_absurd_values() {
    let case = Case::new();
    let cases: [(&str, &str, &[&str]); 3] = [
        (
            "bad-typo.json",
            r#"{"pitch": 38, "slope": -7, "center": 0.5, "invVeiw": {"value": 1}}"#,
            &["bad-typo.json", "invVeiw", "did you mean `invView`"],
        ),
        (
            "bad-pitch.json",
            r#"{"pitch": 1e300, "slope": -7, "center": 0.5}"#,
            &["bad-pitch.json", "field `pitch`: must be between"],
        ),
        (
            "bad-slope.json",
            r#"{"pitch": 38, "slope": 1e-300, "center": 0.5}"#,
            &["bad-slope.json", "field `slope`"],
        ),
    ];
    for (name, json, needles) in cases {
        let bad = bad_file(&case.path(name), json.as_bytes());
        let result = case.render(&case.photo, &case.depth, &["--calibration", &bad]);
        case.assert_failed_cleanly(&result, needles);
    }
}

/// Issue 26: an unwritable --out was found only after the whole render had run.
#[test]
fn unwritable_out_is_refused_before_any_work() {
    let case = Case::new();
    let board = tiny_board();
    let under_a_file = format!("{}/out", case.photo);
    for out in [under_a_file.as_str(), "/proc/reshader-no-such/out"] {
        let result = run(&[
            "-v",
            "render",
            &case.photo,
            "--depth",
            &case.depth,
            "--board",
            &board,
            "--out",
            out,
        ]);
        case.assert_failed_cleanly(&result, &["cannot write to --out", out]);
        let err = stderr(&result);
        assert!(
            !err.contains("photo ") && !err.contains("rendered"),
            "work was done first: {err}"
        );
    }
    let view_out = case.path("no-such-dir/view.png");
    let result = case.view(&view_out, &["--camera", "0.1,0,0"]);
    case.assert_failed_cleanly(&result, &["no-such-dir", "does not exist"]);
    let result = run(&[
        "convert",
        &case.photo,
        "--board",
        &board,
        "--out",
        &under_a_file,
    ]);
    case.assert_failed_cleanly(&result, &["cannot write to --out"]);
    assert!(result.stdout.is_empty(), "a photo was attempted");
}

/// Issue 26: `--model x.onnx` said "stream did not contain valid UTF-8".
#[test]
fn model_given_as_its_onnx_file_names_the_manifest() {
    let case = Case::new();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures");
    let onnx = fixtures.join("reshade-fixture-fp32-encoder.onnx");
    let onnx = onnx.display().to_string();
    let result = case.render(&case.photo, &case.depth, &["--model", &onnx]);
    case.assert_failed_cleanly(
        &result,
        &[
            "is an ONNX graph",
            "the .json file beside the .onnx",
            "reshade-fixture-fp32-encoder.json",
        ],
    );
    assert!(!stderr(&result).contains("UTF-8"), "{}", stderr(&result));
    let binary = bad_file(&case.path("bad-model.bin"), &[0xff, 0xfe, 0x00, 0x9c]);
    let result = case.render(&case.photo, &case.depth, &["--model", &binary]);
    case.assert_failed_cleanly(&result, &["bad-model.bin", "is not a model manifest"]);
}

/// Issue 26: memory ceilings crashed (SIGABRT at --max-memory 64M, panics inside tract
/// at 100M-150M, aborts for 20000x20000 views or a 32768x32768 calibrated panel). The
/// sizes are now estimated before any work and refused with the figure and the option
/// to raise; nothing is written and the exit code is 1.
#[test]
fn memory_ceilings_refuse_with_the_figure_before_any_work() {
    let case = Case::new();
    let expect_refusal = |result: &std::process::Output, needles: &[&str]| {
        let err = stderr(result);
        assert_eq!(result.status.code(), Some(1), "{err}");
        for needle in ["would need about", "raise --max-memory"]
            .iter()
            .chain(needles)
        {
            assert!(err.contains(needle), "expected {needle:?} in: {err}");
        }
    };
    let huge_views = std::fs::read_to_string(tiny_board())
        .unwrap()
        .replace("view_width = 24", "view_width = 20000")
        .replace("view_height = 16", "view_height = 20000");
    let board = bad_file(&case.path("bad-board.toml"), huge_views.as_bytes());
    let out = case.out();
    let result = run(&[
        "render",
        &case.photo,
        "--depth",
        &case.depth,
        "--board",
        &board,
        "--out",
        &out,
    ]);
    expect_refusal(&result, &["20000x20000", "GiB"]);
    let visual = bad_file(
        &case.path("bad-screen.json"),
        br#"{"pitch": 38, "slope": -7, "center": 0.5, "screenW": 32768, "screenH": 32768}"#,
    );
    let result = case.render(&case.photo, &case.depth, &["--calibration", &visual]);
    expect_refusal(&result, &["panel"]);
    // Without the panel it fits.
    let result = case.render(
        &case.photo,
        &case.depth,
        &["--calibration", &visual, "--only", "views"],
    );
    assert_eq!(result.status.code(), Some(0), "{}", stderr(&result));
    std::fs::remove_dir_all(case.out()).unwrap();
    let weave_out = case.path("panel.png");
    let views = case.path("bad-views");
    std::fs::create_dir(&views).unwrap();
    let result = run(&[
        "weave",
        &views,
        "--board",
        &tiny_board(),
        "--calibration",
        &visual,
        "--out",
        &weave_out,
    ]);
    expect_refusal(&result, &["weaving"]);
    // A ceiling below what the depth network needs to load: render, depth, convert.
    let portrait = "looking-glass-portrait";
    let result = run(&[
        "--max-memory",
        "64M",
        "render",
        &case.photo,
        "--board",
        portrait,
        "--out",
        &out,
    ]);
    expect_refusal(&result, &["--max-memory 64 MiB", "depth network"]);
    let depth_out = case.path("depth-out.npy");
    let result = run(&[
        "--max-memory",
        "64M",
        "depth",
        &case.photo,
        "--out",
        &depth_out,
    ]);
    expect_refusal(&result, &["loading the depth network"]);
    let result = run(&[
        "--max-memory",
        "64M",
        "convert",
        &case.photo,
        "--board",
        portrait,
        "--out",
        &out,
    ]);
    expect_refusal(&result, &["loading the depth network"]);
    // 48 views of 420x560 from a depth file: over 100M, refused, not aborted.
    let result = run(&[
        "--max-memory",
        "100M",
        "render",
        &case.photo,
        "--depth",
        &case.depth,
        "--board",
        portrait,
        "--out",
        &out,
    ]);
    expect_refusal(&result, &["48 views of 420x560"]);
    case.assert_failed_cleanly(&result, &[]);
}
