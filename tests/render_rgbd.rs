//! `render`'s RGB-D product (issue 22): the photo beside its depth as 8-bit grey, near =
//! white, with the focus and depthiness of the views in run.json and in the PNG.

use crate::spine_support;

use std::collections::HashMap;
use std::path::Path;

use serde_json::Value;
use spine_support::*;

fn render(out: &Path, extra: &[&str]) -> Value {
    let (photo, depth) = write_scene(out.parent().unwrap());
    let (board, out_s) = (tiny_board(), out.display().to_string());
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

fn png_text(path: &Path) -> HashMap<String, String> {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let reader = png::Decoder::new(file).read_info().unwrap();
    reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .map(|c| (c.keyword.clone(), c.text.clone()))
        .collect()
}

#[test]
fn rgbd_is_the_photo_beside_its_depth_with_the_settings_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let run = render(&out, &["--only", "rgbd"]);
    assert_eq!(
        run["outputs"],
        serde_json::json!(["rgbd.png", "run.json"]),
        "only the RGB-D image and the record"
    );
    let rgbd = load(&out.join("rgbd.png"));
    // The tiny board's views are the photo's size, so the photo is kept as it is.
    assert_eq!(rgbd.dimensions(), (2 * PHOTO_W, PHOTO_H));
    let photo = scene_photo();
    let left = image::imageops::crop_imm(&rgbd, 0, 0, PHOTO_W, PHOTO_H).to_image();
    assert!(left == photo, "the colour half is the photo");

    // The depth half: grey, and nearer never darker.
    let depth = scene_depth();
    let grey: Vec<u8> = (0..PHOTO_W * PHOTO_H)
        .map(|i| {
            let p = rgbd.get_pixel(PHOTO_W + i % PHOTO_W, i / PHOTO_W).0;
            assert!(p[0] == p[1] && p[1] == p[2], "grey: {p:?}");
            p[0]
        })
        .collect();
    let mut order: Vec<usize> = (0..depth.len()).collect();
    order.sort_by(|&a, &b| depth[a].total_cmp(&depth[b]));
    for pair in order.windows(2) {
        let (near, far) = (pair[0], pair[1]);
        assert!(
            grey[near] >= grey[far],
            "depth {} is grey {} but depth {} is grey {}",
            depth[near],
            grey[near],
            depth[far],
            grey[far]
        );
    }
    assert_eq!(grey[order[0]], 255, "the nearest depth is white");
    assert_eq!(grey[*order.last().unwrap()], 0, "the farthest is black");

    // The settings, in run.json and in the PNG itself.
    let record = &run["rgbd"];
    assert_eq!(record["file"], "rgbd.png");
    assert_eq!(record["focus"], 2.0);
    assert_eq!(record["depthiness"], 0.5);
    assert_eq!(record["depth_near"], 1.5);
    assert!((record["depth_far"].as_f64().unwrap() - 4.5).abs() < 1e-5);
    let text = png_text(&out.join("rgbd.png"));
    assert_eq!(text["Focus"], "2");
    assert_eq!(text["Depthiness"], "0.5");
    assert_eq!(text["Depth near"], "1.5");
    assert!(
        text["Depth encoding"].contains("255 = depth_near"),
        "{text:?}"
    );
    assert!(text["Software"].starts_with("reshader "), "{text:?}");
}

#[test]
fn the_default_depthiness_is_the_one_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let (photo, depth) = write_scene(tmp.path());
    let (board, out_s) = (tiny_board(), out.display().to_string());
    let result = run(&[
        "render", &photo, "--depth", &depth, "--board", &board, "--out", &out_s,
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    let run: Value = serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap();
    let used = run["geometry"]["rig"]["depthiness"].as_f64().unwrap();
    assert_eq!(run["rgbd"]["depthiness"].as_f64().unwrap(), used);
    assert_eq!(run["rgbd"]["focus"], run["geometry"]["focus"]);
    let text = png_text(&out.join("rgbd.png"));
    assert_eq!(text["Depthiness"].parse::<f64>().unwrap(), used);
}
