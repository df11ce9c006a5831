//! Shared helpers for the reshading integration tests: the committed fixture model and a
//! reader for the N-D `.npy` reference tensors it ships with.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use reshader::depth::DepthMap;
use reshader::engine::manifest::{Manifest, Precision, Task};
use reshader::engine::{self, Engine};
use reshader::io::photo::SrgbImage;

/// The fixture directory (`RESHADER_FIXTURE_DIR` overrides it for trying other exports).
pub fn fixture_dir() -> PathBuf {
    std::env::var_os("RESHADER_FIXTURE_DIR").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures"),
        PathBuf::from,
    )
}

/// The fixture manifest for `task` at `precision`.
pub fn manifest_path(task: Task, precision: Precision) -> PathBuf {
    manifest_path_in(&fixture_dir(), task, precision)
}

/// The one manifest for `task` at `precision` in `dir`.
pub fn manifest_path_in(dir: &Path, task: Task, precision: Precision) -> PathBuf {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("fixture directory {}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .filter(|p| Manifest::load(p).is_ok_and(|m| m.task == task && m.precision == precision))
        .collect();
    found.sort();
    assert_eq!(
        found.len(),
        1,
        "expected one {task} {precision} manifest in {}, found {found:?}",
        dir.display()
    );
    found.remove(0)
}

pub fn tract(threads: usize) -> Arc<dyn Engine> {
    engine::by_name("tract", threads).expect("tract is always built")
}

/// The runtime's options without the gate, so that every view is the network's own: what
/// a comparison with PyTorch's outputs needs.
pub fn ungated() -> reshader::reshade::net::NetOptions {
    reshader::reshade::net::NetOptions {
        gate: 0.0,
        ..Default::default()
    }
}

/// An N-D little-endian float32 `.npy` array: (shape, values).
pub fn read_npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "{} is not .npy", path.display());
    let (len, start) = if bytes[6] == 1 {
        (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10)
    } else {
        (
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            12,
        )
    };
    let header = std::str::from_utf8(&bytes[start..start + len]).unwrap();
    assert!(
        header.contains("'descr': '<f4'"),
        "{}: {header}",
        path.display()
    );
    assert!(
        header.contains("'fortran_order': False"),
        "{}: {header}",
        path.display()
    );
    let shape_text = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    let data: Vec<f32> = bytes[start + len..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(
        data.len(),
        shape.iter().product::<usize>(),
        "{}",
        path.display()
    );
    (shape, data)
}

/// A planar [1,3,H,W] tensor as an image.
pub fn image_from_planar(shape: &[usize], data: &[f32]) -> SrgbImage {
    let (h, w) = (shape[2], shape[3]);
    let mut img = SrgbImage::new(w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            let at = |c: usize| data[(c * h + y) * w + x];
            img.put(x as u32, y as u32, [at(0), at(1), at(2)]);
        }
    }
    img
}

/// Depth whose network disparity `clamp(0.25/depth, 0, 1)` is `d` (d = 0 → infinitely far).
pub fn depth_from_disparity(w: usize, h: usize, d: &[f32]) -> DepthMap {
    DepthMap::new(
        w,
        h,
        d.iter()
            .map(|&d| if d > 0.0 { 0.25 / d } else { f32::INFINITY })
            .collect(),
    )
}

/// A smooth test photo with edges and its depth (1–5 units).
pub fn scene(w: u32, h: u32) -> (SrgbImage, DepthMap) {
    reshader::eval::reshade::test_scene(w, h)
}

pub fn max_abs_diff(a: &SrgbImage, b: &SrgbImage) -> f32 {
    assert_eq!((a.width(), a.height()), (b.width(), b.height()));
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Standard base64 (with padding) to bytes.
pub fn base64(text: &str) -> Vec<u8> {
    let value = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let mut out = Vec::with_capacity(text.len() * 3 / 4);
    for chunk in text.trim_end_matches('=').as_bytes().chunks(4) {
        let bits = chunk
            .iter()
            .enumerate()
            .fold(0u32, |acc, (i, &c)| acc | value(c) << (18 - 6 * i));
        out.extend_from_slice(&bits.to_be_bytes()[1..chunk.len()]);
    }
    out
}

pub fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}
