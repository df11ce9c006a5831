//! One rendered example of the dataset, loaded and tone-mapped for the evaluation.

use std::path::{Path, PathBuf};

use crate::depth::{read_raw, DepthMap};
use crate::io::photo::SrgbImage;
use crate::views::Intrinsics;

use super::{EvalError, SKY_DEPTH};

pub(super) struct Example {
    pub id: String,
    pub input: SrgbImage,
    pub reshaded: SrgbImage,
    pub novel: SrgbImage,
    /// The depth the methods relocate with.
    pub depth: DepthMap,
    /// The renderer's depth, which defines the regions.
    pub true_depth: DepthMap,
    pub valid: Vec<bool>,
    pub source: Intrinsics,
    pub offset: [f64; 3],
}

/// The example folders under `root` (those with a meta.json), in name order.
pub(super) fn example_dirs(root: &Path, limit: Option<usize>) -> Result<Vec<PathBuf>, EvalError> {
    let io = |source| EvalError::Io {
        path: root.into(),
        source,
    };
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
        .map_err(io)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("meta.json").is_file())
        .collect();
    dirs.sort();
    dirs.truncate(limit.unwrap_or(usize::MAX));
    if dirs.is_empty() {
        return Err(EvalError::Empty(root.into()));
    }
    Ok(dirs)
}

/// Loads one example folder.
pub(super) fn load_example(dir: &Path, exposure: f32, gamma: f32) -> Result<Example, EvalError> {
    let meta_path = dir.join("meta.json");
    let text = std::fs::read_to_string(&meta_path).map_err(|source| EvalError::Io {
        path: meta_path.clone(),
        source,
    })?;
    let meta: serde_json::Value = serde_json::from_str(&text).map_err(|e| EvalError::Meta {
        path: meta_path.clone(),
        detail: e.to_string(),
    })?;
    let number = |v: &serde_json::Value, what: &str| {
        v.as_f64().ok_or_else(|| EvalError::Meta {
            path: meta_path.clone(),
            detail: format!("{what} is missing or not a number"),
        })
    };
    let cam = &meta["input_camera"];
    let t = &meta["novel_offset"];
    let offset = [
        number(&t[0], "novel_offset[0]")?,
        number(&t[1], "novel_offset[1]")?,
        number(&t[2], "novel_offset[2]")?,
    ];
    let input = load_hdr(&dir.join("input.exr"), exposure, gamma)?;
    let (w, h) = (input.width(), input.height());
    // The renderer puts pixel centres at integers; ours are at +0.5.
    let source = Intrinsics {
        fx: number(&cam["fx"], "input_camera.fx")?,
        fy: number(&cam["fy"], "input_camera.fy")?,
        cx: number(&cam["cx"], "input_camera.cx")? + 0.5,
        cy: number(&cam["cy"], "input_camera.cy")? + 0.5,
        width: w,
        height: h,
    };
    let depth_path = dir.join("depth.exr");
    let raw = read_raw(&depth_path).map_err(|source| EvalError::DepthFile {
        path: depth_path.clone(),
        source,
    })?;
    if (raw.width, raw.height) != (w as usize, h as usize) {
        return Err(EvalError::Meta {
            path: depth_path,
            detail: format!("{}x{} but input.exr is {w}x{h}", raw.width, raw.height),
        });
    }
    let depth: Vec<f32> = raw
        .values
        .iter()
        .map(|&z| {
            if z.is_finite() && z > 0.0 {
                z.min(SKY_DEPTH)
            } else {
                SKY_DEPTH
            }
        })
        .collect();
    let depth_copy = depth.clone();
    let mask_path = dir.join("mask.png");
    let mask = image::open(&mask_path)
        .map_err(|source| EvalError::Decode {
            path: mask_path.clone(),
            source,
        })?
        .into_luma8();
    Ok(Example {
        id: dir
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
        reshaded: load_hdr(&dir.join("reshaded.exr"), exposure, gamma)?,
        novel: load_hdr(&dir.join("novel.exr"), exposure, gamma)?,
        input,
        depth: DepthMap::new(w as usize, h as usize, depth),
        true_depth: DepthMap::new(w as usize, h as usize, depth_copy),
        valid: mask.as_raw().iter().map(|&m| m > 127).collect(),
        source,
        offset,
    })
}

/// Reads a linear HDR image and tone-maps it: clamp((x · exposure)^(1/gamma), 0, 1).
fn load_hdr(path: &Path, exposure: f32, gamma: f32) -> Result<SrgbImage, EvalError> {
    let img = image::open(path)
        .map_err(|source| EvalError::Decode {
            path: path.into(),
            source,
        })?
        .into_rgb32f();
    let mut out = SrgbImage::from_rgb32f(img);
    let (w, h) = (out.width(), out.height());
    for y in 0..h {
        for x in 0..w {
            let c = out
                .get(x, y)
                .map(|v| (v.max(0.0) * exposure).powf(1.0 / gamma).clamp(0.0, 1.0));
            out.put(x, y, c);
        }
    }
    Ok(out)
}
