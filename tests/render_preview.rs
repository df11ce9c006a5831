//! `render`'s previews (issue 22): `preview.gif` sweeps the views left to right and back,
//! and `preview.html` shows the view under the pointer, opened in a real browser when
//! `RESHADER_BROWSER` names one (scripts/test installs Debian's Chromium and sets it).

use crate::spine_support;

use std::path::{Path, PathBuf};
use std::process::Command;

use image::{Rgb, RgbImage};
use reshader::io::preview::{self, animation, page};
use serde_json::Value;
use spine_support::*;

const VIEWS: usize = 4;
const VIEW_W: u32 = 640;
const VIEW_H: u32 = 360;

/// A board whose views are larger than a preview frame, so that the previews shrink
/// them.
const BOARD: &str = r#"
name = "preview-test"
description = "4 views of 640x360"
width = 1280
height = 720
views = 4
quilt_cols = 2
quilt_rows = 2
view_width = 640
view_height = 360
view_cone_deg = 40.0
subpixels = "rgb"

[looking_glass]
pitch = 38.0
slope = -7.0
center = 0.5
inv_view = true
dpi = 100.0
"#;

/// A striped wall at depth 4 with a bright square at depth 1.5 before it: the square
/// moves across the wall from view to view.
fn write_scene(dir: &Path) -> (String, String, String) {
    let inside = |x: u32, y: u32| (240..400).contains(&x) && (100..260).contains(&y);
    let photo = RgbImage::from_fn(VIEW_W, VIEW_H, |x, y| {
        if inside(x, y) {
            Rgb([240, 200, 40])
        } else if (x / 32) % 2 == 0 {
            Rgb([30, 60, 160])
        } else {
            Rgb([20, 140, 90])
        }
    });
    let depth: Vec<f32> = (0..VIEW_W * VIEW_H)
        .map(|i| {
            if inside(i % VIEW_W, i / VIEW_W) {
                1.5
            } else {
                4.0
            }
        })
        .collect();
    let (photo_path, depth_path, board) = (
        dir.join("photo.png"),
        dir.join("depth.npy"),
        dir.join("board.toml"),
    );
    photo.save(&photo_path).unwrap();
    write_npy(&depth_path, VIEW_H as usize, VIEW_W as usize, &depth);
    std::fs::write(&board, BOARD).unwrap();
    let s = |p: PathBuf| p.display().to_string();
    (s(photo_path), s(depth_path), s(board))
}

fn render(dir: &Path, only: &str) -> (PathBuf, Value) {
    let (photo, depth, board) = write_scene(dir);
    let out = dir.join("out");
    let result = run(&[
        "render",
        &photo,
        "--depth",
        &depth,
        "--board",
        &board,
        "--focus",
        "2.5",
        "--depthiness",
        "1",
        "--only",
        only,
        "--out",
        &out.display().to_string(),
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    let run = serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap();
    (out, run)
}

/// The mean difference per channel of two images of one size, in levels.
fn mean_difference(a: &RgbImage, b: &RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let total: u64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| u64::from(x.abs_diff(*y)))
        .sum();
    total as f64 / a.as_raw().len() as f64
}

/// The view files shrunk as the previews shrink them.
fn preview_views(out: &Path) -> Vec<RgbImage> {
    let views: Vec<RgbImage> = (0..VIEWS)
        .map(|i| load(&out.join(format!("views/view_{i:02}.png"))))
        .collect();
    preview::shrink(&views)
}

#[test]
fn previews_are_products_recorded_in_run_json() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, run) = render(tmp.path(), "views,preview,html");
    let outputs: Vec<&str> = run["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(
        &outputs[VIEWS..],
        ["preview.gif", "preview.html", "run.json"]
    );
    for stage in ["preview_shrink", "preview_gif", "preview_html"] {
        assert!(run["timings_ms"][stage].is_number(), "timing {stage}");
    }

    // The GIF: the frames shrunk to 512 on the long side, the sweep 0 1 2 3 2 1.
    let views = preview_views(&out);
    let bytes = std::fs::read(out.join("preview.gif")).unwrap();
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options.read_info(bytes.as_slice()).unwrap();
    assert_eq!((decoder.width(), decoder.height()), (512, 288));
    let mut canvas = RgbImage::new(512, 288);
    let mut shown = Vec::new();
    while let Some(frame) = decoder.read_next_frame().unwrap() {
        let (fw, fl, ft) = (
            u32::from(frame.width),
            u32::from(frame.left),
            u32::from(frame.top),
        );
        for (i, p) in frame.buffer.chunks(4).enumerate() {
            if p[3] != 0 {
                let (x, y) = (fl + i as u32 % fw, ft + i as u32 / fw);
                canvas.put_pixel(x, y, Rgb([p[0], p[1], p[2]]));
            }
        }
        let nearest = (0..VIEWS)
            .min_by(|&a, &b| {
                mean_difference(&canvas, &views[a]).total_cmp(&mean_difference(&canvas, &views[b]))
            })
            .unwrap();
        assert!(mean_difference(&canvas, &views[nearest]) < 3.0);
        shown.push(nearest);
    }
    assert_eq!(shown, animation::sweep(VIEWS));

    let html = std::fs::read_to_string(out.join("preview.html")).unwrap();
    assert_eq!(html.matches("data:image/jpeg;base64,").count(), VIEWS);
    assert!(html.contains("<title>photo.png: reshader preview</title>"));
}

/// Opens `page` in headless Chromium with `fragment` after its address and returns the
/// top-left `width`×`height` of the window.
fn screenshot(browser: &str, page: &Path, fragment: &str, (width, height): (u32, u32)) -> RgbImage {
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("shot.png");
    let profile = dir.path().join("profile");
    let url = format!("file://{}{fragment}", page.display());
    let result = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            "--run-all-compositor-stages-before-draw",
            "--virtual-time-budget=5000",
            "--window-size=800,600",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(&url)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {browser}: {e}"));
    assert!(
        result.status.success() && shot.exists(),
        "{browser} took no screenshot of {url}: {}",
        stderr(&result)
    );
    image::imageops::crop_imm(&load(&shot), 0, 0, width, height).to_image()
}

#[test]
fn the_page_in_a_browser_shows_the_view_under_the_pointer() {
    let Ok(browser) = std::env::var("RESHADER_BROWSER") else {
        eprintln!("RESHADER_BROWSER is not set: the page is not opened in a browser");
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (out, _) = render(tmp.path(), "views,html");
    let views = preview_views(&out);
    let size = views[0].dimensions();
    let page = out.join("preview.html");
    // No pointer yet: the middle view; then pointers over three strips. Every position
    // goes through the page's pointermove handler.
    let mut seen = Vec::new();
    for (fragment, fraction) in [("", 0.5), ("#x=0.1", 0.1), ("#x=0.3", 0.3), ("#x=0.9", 0.9)] {
        let expected = page::view_at(fraction, VIEWS);
        let shot = screenshot(&browser, &page, fragment, size);
        let differences: Vec<f64> = views.iter().map(|v| mean_difference(&shot, v)).collect();
        assert!(
            differences[expected] < 3.0,
            "{fragment:?}: the window differs from view {expected} by {:.2} levels",
            differences[expected]
        );
        for (v, d) in differences.iter().enumerate() {
            assert!(
                v == expected || *d > 2.0 * differences[expected],
                "{fragment:?}: view {expected} expected, but view {v} is as close: {differences:?}"
            );
        }
        seen.push(shot);
    }
    assert!(
        mean_difference(&seen[1], &seen[3]) > 5.0,
        "two positions, two pictures"
    );
}
