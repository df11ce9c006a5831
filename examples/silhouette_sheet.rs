//! Contact sheet of silhouettes in the outermost views of renders, where depth steps
//! move the most: fringes, streaks and stretched border columns show there first.
//!
//! ```text
//! cargo run --example silhouette_sheet -- OUT.png WxH+X+Y[,WxH+X+Y...] VIEWS_DIR...
//! ```
//!
//! Each `VIEWS_DIR` is the `views/` folder of a `reshader render … --only views`; each
//! row is one crop box (view pixels), with, per folder, the crop of its first view and
//! of its last, magnified 3× without smoothing. `scripts/silhouette-sheet` renders and
//! calls this.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use image::{imageops, Rgb, RgbImage};

const ZOOM: u32 = 3;
const GAP: u32 = 4;

struct Crop {
    w: u32,
    h: u32,
    x: u32,
    y: u32,
}

fn parse_box(s: &str) -> Result<Crop> {
    let bad = || format!("crop box {s:?}: expected WxH+X+Y, e.g. 90x90+0+180");
    let (size, at) = s.split_once('+').with_context(bad)?;
    let (w, h) = size.split_once('x').with_context(bad)?;
    let (x, y) = at.split_once('+').with_context(bad)?;
    let n = |v: &str| v.parse::<u32>().with_context(bad);
    Ok(Crop {
        w: n(w)?,
        h: n(h)?,
        x: n(x)?,
        y: n(y)?,
    })
}

/// The first and last `view_NN.png` of a folder.
fn outermost(dir: &Path) -> Result<[RgbImage; 2]> {
    let mut views: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read {}", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("view_") && n.ends_with(".png"))
        })
        .collect();
    views.sort();
    let (Some(first), Some(last)) = (views.first(), views.last()) else {
        bail!("{} holds no view_NN.png", dir.display());
    };
    let open = |p: &Path| -> Result<RgbImage> {
        Ok(image::open(p)
            .with_context(|| format!("cannot decode {}", p.display()))?
            .into_rgb8())
    };
    Ok([open(first)?, open(last)?])
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [out, boxes, dirs @ ..] = args.as_slice() else {
        bail!("usage: silhouette_sheet OUT.png WxH+X+Y[,WxH+X+Y...] VIEWS_DIR...");
    };
    if dirs.is_empty() {
        bail!("usage: silhouette_sheet OUT.png WxH+X+Y[,WxH+X+Y...] VIEWS_DIR...");
    }
    let boxes: Vec<Crop> = boxes.split(',').map(parse_box).collect::<Result<_>>()?;
    let views: Vec<[RgbImage; 2]> = dirs
        .iter()
        .map(|d| outermost(Path::new(d)))
        .collect::<Result<_>>()?;
    let tiles = 2 * views.len() as u32;
    let width = boxes.iter().map(|b| b.w).max().unwrap_or(0) * ZOOM;
    let height: u32 = boxes.iter().map(|b| b.h * ZOOM + GAP).sum();
    let mut sheet = RgbImage::from_pixel(tiles * (width + GAP), height, Rgb([255, 255, 255]));
    let mut top = 0;
    for b in &boxes {
        for (k, image) in views.iter().flatten().enumerate() {
            if b.x + b.w > image.width() || b.y + b.h > image.height() {
                bail!(
                    "crop box {}x{}+{}+{} lies outside the {}x{} views",
                    b.w,
                    b.h,
                    b.x,
                    b.y,
                    image.width(),
                    image.height()
                );
            }
            let crop = imageops::crop_imm(image, b.x, b.y, b.w, b.h).to_image();
            let zoomed =
                imageops::resize(&crop, b.w * ZOOM, b.h * ZOOM, imageops::FilterType::Nearest);
            let left = k as u32 * (width + GAP);
            imageops::replace(&mut sheet, &zoomed, i64::from(left), i64::from(top));
        }
        top += b.h * ZOOM + GAP;
    }
    sheet
        .save(out)
        .with_context(|| format!("cannot write {out}"))?;
    eprintln!(
        "wrote {out}: {} rows, first | last view of {}",
        boxes.len(),
        dirs.join(", ")
    );
    Ok(())
}
