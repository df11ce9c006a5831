//! End-to-end renders of a tiny synthetic scene on a tiny board, against committed
//! goldens: views with a tolerance (warping may shift by rounding), woven frames exactly.
//! `RESHADER_UPDATE_GOLDENS=1 cargo test --test main spine_render::` rewrites the goldens.

use crate::spine_support;

use std::path::Path;

use image::RgbImage;
use serde_json::Value;
use spine_support::*;

const VIEWS: usize = 6;

fn render_tiny(out: &Path, extra: &[&str]) -> Value {
    let tmp = out.parent().unwrap();
    let (photo, depth) = write_scene(tmp);
    let board = tiny_board();
    let out_s = out.display().to_string();
    let mut args = vec![
        "render",
        &photo,
        "--depth",
        &depth,
        "--board",
        &board,
        "--focus",
        "2",
        "--depthiness",
        "0.5",
        "--out",
        &out_s,
    ];
    args.extend_from_slice(extra);
    let result = run(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap()
}

fn updating() -> bool {
    std::env::var_os("RESHADER_UPDATE_GOLDENS").is_some()
}

/// Warped views may differ from the goldens by interpolation rounding, not in content.
fn assert_close(actual: &RgbImage, golden: &RgbImage, what: &str) {
    assert_eq!(actual.dimensions(), golden.dimensions(), "{what}: size");
    let diffs: Vec<u8> = actual
        .as_raw()
        .iter()
        .zip(golden.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .collect();
    let mean = diffs.iter().map(|&d| f64::from(d)).sum::<f64>() / diffs.len() as f64;
    let large = diffs.iter().filter(|&&d| d > 16).count();
    assert!(mean < 1.0, "{what}: mean difference {mean:.2} levels");
    assert!(
        large * 100 <= diffs.len(),
        "{what}: {large} values differ by > 16 levels"
    );
}

#[test]
fn views_and_woven_frames_match_goldens() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    render_tiny(&out, &[]);
    let golden = golden_dir();
    let mut names: Vec<String> = (0..VIEWS)
        .map(|i| format!("views/view_{i:02}.png"))
        .collect();
    names.extend(["panel.png", "sbs.png", "quilt_qs3x2a1.5.png"].map(String::from));
    if updating() {
        for name in &names {
            let dest = golden.join(name);
            std::fs::create_dir_all(dest.parent().unwrap()).unwrap();
            std::fs::copy(out.join(name), dest).unwrap();
        }
    }
    for name in &names[..VIEWS] {
        assert_close(&load(&out.join(name)), &load(&golden.join(name)), name);
    }
    // Weaving is exact: the golden views woven by the CLI give the golden panel.
    let panel = tmp.path().join("panel_from_goldens.png");
    let golden_views = golden.join("views").display().to_string();
    let board = tiny_board();
    let result = run(&[
        "weave",
        &golden_views,
        "--board",
        &board,
        "--out",
        &panel.display().to_string(),
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(
        load(&panel) == load(&golden.join("panel.png")),
        "woven panel differs from golden"
    );
}

#[test]
fn render_products_are_consistent_with_its_views() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    render_tiny(&out, &[]);
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
    let views: Vec<RgbImage> = (0..VIEWS)
        .map(|i| load(&out.join(format!("views/view_{i:02}.png"))))
        .collect();
    assert!(views.iter().all(|v| v.dimensions() == (24, 16)));
    // The quilt: view 0 bottom-left, left to right, then upward.
    let quilt = load(&out.join("quilt_qs3x2a1.5.png"));
    assert_eq!(quilt.dimensions(), (72, 32));
    for (i, view) in views.iter().enumerate() {
        let (col, row_from_bottom) = (i as u32 % 3, i as u32 / 3);
        let tile = image::imageops::crop_imm(&quilt, col * 24, (1 - row_from_bottom) * 16, 24, 16)
            .to_image();
        assert!(tile == *view, "quilt tile of view {i}");
    }
    // sbs: the outermost pair.
    let sbs = load(&out.join("sbs.png"));
    assert!(image::imageops::crop_imm(&sbs, 0, 0, 24, 16).to_image() == views[0]);
    assert!(image::imageops::crop_imm(&sbs, 24, 0, 24, 16).to_image() == views[VIEWS - 1]);
    // The panel is the board's size and every subpixel comes from some view.
    let panel = load(&out.join("panel.png"));
    assert_eq!(panel.dimensions(), (64, 48));
    // The square is nearer than the focus plane: it moves against the camera, so it sits
    // further right in view 0 (leftmost camera) than in the last view.
    let red_centre = |v: &RgbImage| {
        let xs: Vec<u32> = v
            .enumerate_pixels()
            .filter(|(_, _, p)| p.0[0] > 200 && p.0[2] < 100)
            .map(|(x, _, _)| x)
            .collect();
        xs.iter().sum::<u32>() as f64 / xs.len() as f64
    };
    assert!(red_centre(&views[0]) > red_centre(&views[VIEWS - 1]) + 1.0);
}

#[test]
fn run_json_records_inputs_cameras_and_stages() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let run = render_tiny(&out, &[]);
    let photo_sha = reshader::io::record::sha256_file(&tmp.path().join("photo.png")).unwrap();
    assert_eq!(run["inputs"]["photo"]["sha256"], photo_sha.as_str());
    assert_eq!(run["inputs"]["photo"]["fov_source"], "default");
    assert_eq!(run["inputs"]["depth"]["kind"], "depth");
    assert!(run["inputs"]["board_file"]["sha256"].is_string());
    assert_eq!(run["board"]["name"], "tiny-test");
    assert_eq!(run["reshade"], "identity (no model)");
    assert_eq!(run["geometry"]["focus"], 2.0);
    assert_eq!(run["geometry"]["depthiness_source"], "command_line");
    let xs: Vec<f64> = run["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["camera"][0].as_f64().unwrap())
        .collect();
    assert_eq!(xs.len(), VIEWS);
    assert!(
        xs.windows(2).all(|w| w[0] < w[1]),
        "view 0 leftmost: {xs:?}"
    );
    assert!((xs[0] + xs[VIEWS - 1]).abs() < 1e-12);
    // Outermost cameras: focus · tan(cone/2) · depthiness.
    assert!((xs[VIEWS - 1] - 2.0 * 20f64.to_radians().tan() * 0.5).abs() < 1e-9);
    for stage in ["load", "reshade", "relocate", "weave", "write"] {
        assert!(run["timings_ms"][stage].is_number(), "stage {stage}");
    }
    assert_eq!(run["outputs"].as_array().unwrap().len(), VIEWS + 7);
}

#[test]
fn only_limits_the_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    render_tiny(&out, &["--only", "panel,quilt"]);
    assert_eq!(
        entries(&out),
        ["panel.png", "quilt_qs3x2a1.5.png", "run.json"]
    );
}

#[test]
fn calibration_changes_the_weave() {
    let tmp = tempfile::tempdir().unwrap();
    let plain = tmp.path().join("plain");
    render_tiny(&plain, &["--only", "panel"]);
    let calibrated = tmp.path().join("cal");
    let cal = support_dir().join("visual.json").display().to_string();
    let run = render_tiny(&calibrated, &["--only", "panel", "--calibration", &cal]);
    assert!(run["inputs"]["calibration"]["sha256"].is_string());
    assert!(load(&plain.join("panel.png")) != load(&calibrated.join("panel.png")));
}

#[test]
fn view_command_reproduces_a_render_view() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    // Crop framing fits the views a command serves (all of a render's, the one of
    // `view`), so the views are compared in the input's framing.
    let run = render_tiny(&out, &["--only", "views", "--border", "extend"]);
    let camera_of = |k: usize| {
        let c = &run["views"][k]["camera"];
        format!("{},{},{}", c[0], c[1], c[2])
    };
    let photo = tmp.path().join("photo.png").display().to_string();
    let depth = tmp.path().join("depth.npy").display().to_string();
    // The LDI is prepared for the widest view it serves: `view` prepares for its own
    // camera, which is the render's widest for view 0, so that view is identical ...
    let outer = tmp.path().join("view0.png");
    let result = run_view(&photo, &depth, &camera_of(0), &outer, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&outer) == load(&out.join("views/view_00.png")));
    // ... while an inner view differs only where its narrower band was inpainted
    // from other background pixels.
    let single = tmp.path().join("view.png");
    let camera = camera_of(1);
    let result = run_view(&photo, &depth, &camera, &single, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    let (a, b) = (load(&single), load(&out.join("views/view_01.png")));
    let diff: Vec<u8> = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(p, q)| p.abs_diff(*q))
        .collect();
    let mean = diff.iter().map(|&d| f64::from(d)).sum::<f64>() / diff.len() as f64;
    assert!(mean < 1.0, "view 1 differs by {mean:.2} levels on average");
    assert!(diff.iter().filter(|&&d| d > 16).count() * 100 < 3 * diff.len());
    // Without reshading the identity reshader changes nothing either.
    let no_reshade = tmp.path().join("view_nr.png");
    let result = run_view(&photo, &depth, &camera, &no_reshade, &["--no-reshade"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&single) == load(&no_reshade));
}

fn run_view(
    photo: &str,
    depth: &str,
    camera: &str,
    out: &Path,
    extra: &[&str],
) -> std::process::Output {
    let out = out.display().to_string();
    let mut args = vec![
        "view", photo, "--depth", depth, "--focus", "2", "--camera", camera, "--out", &out,
        "--border", "extend",
    ];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn reshade_without_model_returns_the_photo_in_every_format() {
    let tmp = tempfile::tempdir().unwrap();
    let (photo, depth) = write_scene(tmp.path());
    for ext in ["png", "exr", "npy"] {
        let out = tmp.path().join(format!("reshaded.{ext}"));
        // run() turns reshading off (RESHADER_MODEL=none), whether or not a model ships.
        let result = run(&[
            "-v",
            "reshade",
            &photo,
            "--depth",
            &depth,
            "--camera",
            "-0.1,0,0.05",
            "--out",
            &out.display().to_string(),
        ]);
        assert!(result.status.success(), "{}", stderr(&result));
        assert!(
            stderr(&result).contains("reshading off"),
            "{}",
            stderr(&result)
        );
        if ext == "npy" {
            let bytes = std::fs::read(&out).unwrap();
            let header = String::from_utf8_lossy(&bytes[..128]);
            assert!(header.contains("'shape': (16, 24, 3)"), "{header}");
            assert_eq!(bytes.len(), 128 + 16 * 24 * 3 * 4);
        } else {
            assert!(load(&out) == scene_photo(), "{ext}");
        }
    }
}

#[test]
fn boards_lists_every_builtin() {
    let result = run(&["boards"]);
    assert!(result.status.success());
    let text = String::from_utf8_lossy(&result.stdout);
    for name in reshader::interleave::Board::builtin_names() {
        assert!(text.contains(name), "{name} missing from:\n{text}");
    }
    assert!(text.contains("1536x2048, 48 views"));
}

/// The files directly in `dir` and in its subfolders, relative and sorted.
fn tree(dir: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if entry.path().is_dir() {
            found.extend(
                tree(&entry.path())
                    .into_iter()
                    .map(|f| format!("{name}/{f}")),
            );
        } else {
            found.push(name);
        }
    }
    found.sort();
    found
}

/// Issue 26: re-rendering into a used --out kept the earlier run's products beside the
/// new ones (the old sbs.png and quilt after `--only panel`, another board's quilt).
#[test]
fn an_output_directory_holds_exactly_one_runs_products() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let run = render_tiny(&out, &[]);
    let listed: Vec<String> = serde_json::from_value(run["outputs"].clone()).unwrap();
    let mut listed_sorted = listed.clone();
    listed_sorted.sort();
    assert_eq!(tree(&out), listed_sorted);
    assert!(listed.iter().any(|o| o.starts_with("quilt_qs3x2")));

    render_tiny(&out, &["--only", "panel"]);
    assert_eq!(tree(&out), ["panel.png", "run.json"]);

    // Another board, another quilt name: the old one goes.
    let board = std::fs::read_to_string(tiny_board())
        .unwrap()
        .replace("quilt_cols = 3", "quilt_cols = 2")
        .replace("quilt_rows = 2", "quilt_rows = 3");
    let board_path = tmp.path().join("tall.toml");
    std::fs::write(&board_path, board).unwrap();
    let board_s = board_path.display().to_string();
    render_tiny(&out, &["--only", "quilt,sbs"]);
    let first: Vec<String> = tree(&out);
    assert!(
        first.iter().any(|f| f.starts_with("quilt_qs3x2")),
        "{first:?}"
    );
    let (photo, depth) = write_scene(tmp.path());
    let out_s = out.display().to_string();
    let result = spine_support::run(&[
        "render", &photo, "--depth", &depth, "--board", &board_s, "--out", &out_s, "--only",
        "quilt",
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    let files = tree(&out);
    assert_eq!(files.len(), 2, "{files:?}");
    assert!(files[0].starts_with("quilt_qs2x3"), "{files:?}");
    assert_eq!(files[1], "run.json");
}

/// `sheet` lays out what reshading does: with no model the two reshaded images are the
/// photo and their difference is black; its outer views are render's outermost views.
#[test]
fn sheet_shows_the_outermost_views_and_their_shading_difference() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("render");
    render_tiny(&out, &["--only", "views"]);
    let photo = tmp.path().join("photo.png").display().to_string();
    let depth = tmp.path().join("depth.npy").display().to_string();
    let sheet_path = tmp.path().join("sheet.png");
    let sheet_s = sheet_path.display().to_string();
    let board = tiny_board();
    let args = [
        "sheet",
        &photo,
        "--depth",
        &depth,
        "--board",
        &board,
        "--focus",
        "2",
        "--depthiness",
        "0.5",
        "--out",
        &sheet_s,
    ];
    let result = run(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(stdout.contains("changes 0.0% of the pixels"), "{stdout}");
    let sheet = load(&sheet_path);
    let (left, right) = (
        load(&out.join("views/view_00.png")),
        load(&out.join(format!("views/view_{:02}.png", VIEWS - 1))),
    );
    let (cw, ch) = (sheet.width() / 3, sheet.height() / 2);
    assert_eq!((cw, ch), left.dimensions());
    let cell = |col: u32, row: u32| {
        image::imageops::crop_imm(&sheet, col * cw, row * ch, cw, ch).to_image()
    };
    assert!(cell(0, 1) == left && cell(2, 1) == right);
    assert!(cell(1, 1).pixels().all(|p| p.0 == [0, 0, 0]));
    // Unwritable or wrong-format outputs are refused before any work.
    let bad = tmp.path().join("sheet.jpg").display().to_string();
    let mut wrong = args;
    wrong[args.len() - 1] = &bad;
    let result = run(&wrong);
    assert_eq!(result.status.code(), Some(1), "{}", stderr(&result));
}

/// Each view is reshaded for a camera on the shading baseline: by default the widest that
/// keeps the outermost cameras within the training data's reach (0.3 units with the focus
/// at 2: 0.3 / (2 tan 20°) = 0.41 of the tiny board's 40° cone), never narrower than the
/// views' own; or as given.
#[test]
fn views_are_reshaded_for_cameras_on_the_shading_baseline() {
    let tmp = tempfile::tempdir().unwrap();
    let (photo, depth) = write_scene(tmp.path());
    let board = tiny_board();
    let out = tmp.path().join("out").display().to_string();
    let base = [
        "render", &photo, "--depth", &depth, "--board", &board, "--focus", "2", "--only", "views",
        "--out", &out,
    ];
    let record = |extra: &[&str]| -> Value {
        let result = run(&[&base[..], extra].concat());
        assert!(result.status.success(), "{}", stderr(&result));
        serde_json::from_slice(&std::fs::read(tmp.path().join("out/run.json")).unwrap()).unwrap()
    };
    let outermost = |run: &Value, key: &str| run["views"][VIEWS - 1][key][0].as_f64().unwrap();
    let full = 2.0 * 20f64.to_radians().tan();

    let narrow = record(&["--depthiness", "0.1"]);
    assert_eq!(
        narrow["geometry"]["shading_depthiness_source"],
        "training_reach"
    );
    assert!((outermost(&narrow, "camera") - 0.1 * full).abs() < 1e-9);
    assert!((outermost(&narrow, "shading_camera") - 0.3).abs() < 1e-9);
    let wide = record(&["--depthiness", "0.5"]);
    assert!((outermost(&wide, "shading_camera") - 0.5 * full).abs() < 1e-9);
    let given = record(&["--depthiness", "0.1", "--shading-depthiness", "0.05"]);
    assert_eq!(
        given["geometry"]["shading_depthiness_source"],
        "command_line"
    );
    assert!((outermost(&given, "shading_camera") - 0.05 * full).abs() < 1e-9);

    let bad = run(&[&base[..], &["--shading-depthiness", "-1"]].concat());
    assert_eq!(bad.status.code(), Some(1), "{}", stderr(&bad));
    assert!(stderr(&bad).contains("depthiness"), "{}", stderr(&bad));
}
