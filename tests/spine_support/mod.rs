//! Shared by the spine's CLI tests: a tiny synthetic scene and ways to run the binary.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use image::{Rgb, RgbImage};

pub const PHOTO_W: u32 = 24;
pub const PHOTO_H: u32 = 16;

pub fn support_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/spine_support")
}

pub fn tiny_board() -> String {
    support_dir().join("tiny-board.toml").display().to_string()
}

pub fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/goldens/spine_tiny")
}

/// Runs the binary with reshading off unless `args` pass --model, so the goldens do not
/// change when a trained model ships in models/reshade.
pub fn run(args: &[&str]) -> Output {
    reshader_command()
        .env("RESHADER_MODEL", "none")
        .args(args)
        .output()
        .expect("reshader runs")
}

/// The binary as a command. A cross-built binary runs under an emulator: cargo runs the
/// test binaries with the target's runner, but the CLI they spawn needs it too, so
/// `RESHADER_TEST_RUNNER` (e.g. `qemu-aarch64-static -L /usr/aarch64-linux-gnu`, split on
/// whitespace) is put in front of it (scripts/cross-aarch64).
pub fn reshader_command() -> Command {
    let exe = env!("CARGO_BIN_EXE_reshader");
    let runner = std::env::var("RESHADER_TEST_RUNNER").unwrap_or_default();
    let mut runner = runner.split_whitespace();
    match runner.next() {
        Some(emulator) => {
            let mut command = Command::new(emulator);
            command.args(runner).arg(exe);
            command
        }
        None => Command::new(exe),
    }
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A sloped wall (depth 3 at the top to 4.5 at the bottom) with a textured square at
/// depth 1.5 in front of it.
pub fn scene_photo() -> RgbImage {
    RgbImage::from_fn(PHOTO_W, PHOTO_H, |x, y| {
        if in_square(x, y) {
            Rgb([220, 40 + (x * 9) as u8, 30 + (y * 11) as u8])
        } else {
            Rgb([(x * 10) as u8, 90 + (y * 8) as u8, 200 - (x * 3) as u8])
        }
    })
}

pub fn scene_depth() -> Vec<f32> {
    (0..PHOTO_W * PHOTO_H)
        .map(|i| {
            let (x, y) = (i % PHOTO_W, i / PHOTO_W);
            if in_square(x, y) {
                1.5
            } else {
                3.0 + 0.1 * y as f32
            }
        })
        .collect()
}

fn in_square(x: u32, y: u32) -> bool {
    (9..16).contains(&x) && (5..11).contains(&y)
}

/// Writes photo.png and depth.npy into `dir`; returns their paths as strings.
pub fn write_scene(dir: &Path) -> (String, String) {
    let photo = dir.join("photo.png");
    scene_photo().save(&photo).unwrap();
    let depth = dir.join("depth.npy");
    write_npy(&depth, PHOTO_H as usize, PHOTO_W as usize, &scene_depth());
    (photo.display().to_string(), depth.display().to_string())
}

pub fn write_npy(path: &Path, rows: usize, cols: usize, data: &[f32]) {
    std::fs::write(path, reshader::io::npy::encode_f32(&[rows, cols], data)).unwrap();
}

/// Names of the entries of `dir`, sorted.
pub fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

pub fn load(path: &Path) -> RgbImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8()
}
