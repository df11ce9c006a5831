//! Depth maps: reading (.npy, 16-bit PNG, PFM, OpenEXR), validation, the normalisation
//! of relative disparity to scene depth, resizing to the photo, and writing.
//!
//! Depth is the distance along the camera's +z axis (OpenCV axes), in scene units.
//! With `--depth-kind depth` the file's units are kept. With `--depth-kind disparity`
//! the values are taken as relative, affine-ambiguous disparity (what monocular depth
//! networks output, larger = nearer) and mapped so that the 2nd percentile lands at
//! depth [`FAR`] and the 98th at [`NEAR`]: the training data's subject range.

pub mod embedded;
mod file;
pub mod holes;
pub mod net;
pub mod refine;

pub use file::{parse_raw, read_raw};

use std::path::{Path, PathBuf};

use crate::io::limits::TooLarge;
use crate::io::npy::NpyError;
use crate::io::output::OutputError;
use crate::io::pfm::PfmError;
use crate::io::photo::SrgbImage;
use holes::{self as depth_holes, HolePolicy, Holes};

/// Depth given to the 98th disparity percentile of a relative-disparity map.
pub const NEAR: f32 = 1.0;
/// Depth given to the 2nd disparity percentile of a relative-disparity map.
pub const FAR: f32 = 5.0;
/// 16-bit PNG values are thousandths of a unit (millimetres for metric depth).
pub const PNG_UNITS_PER_VALUE: f32 = 0.001;
/// Depth and photo aspect ratios may differ this much (relative) before it is an error:
/// enough for maps whose sides were rounded to multiples of 32.
pub const ASPECT_TOLERANCE: f64 = 0.05;
const MAX_SIDE: usize = 1 << 15;
/// Depth files may use any unit, but their values and inverses must stay well inside
/// f32's normal range, where resampling in disparity is exact enough.
pub const MIN_FILE_DEPTH: f32 = 1e-32;
pub const MAX_FILE_DEPTH: f32 = 1e32;

#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    #[error("cannot read depth map {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("depth map {path}: {source}")]
    Npy { path: PathBuf, source: NpyError },
    #[error("depth map {path}: {source}")]
    Pfm { path: PathBuf, source: PfmError },
    #[error("cannot decode depth map {path}: {source}")]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("depth map {path}: {source}")]
    Exr {
        path: PathBuf,
        source: exr::error::Error,
    },
    #[error("depth map {path}: {detail}")]
    Channels { path: PathBuf, detail: String },
    #[error("depth map {path}: unsupported file type; use .npy, .png (16-bit), .pfm or .exr")]
    Extension { path: PathBuf },
    #[error("depth map {path}: size {width}x{height} is out of range")]
    Size {
        path: PathBuf,
        width: usize,
        height: usize,
    },
    #[error("depth map {path}: {source}")]
    TooLarge { path: PathBuf, source: TooLarge },
    #[error(
        "depth map {path} has {count} pixels without depth ({what}; first at x={x}, y={y}), \
         {percent:.2}% of the map; pass --depth-holes fill to fill them from their \
         neighbours and the photo, or --depth-holes far to put them at the farthest depth \
         (a sky)"
    )]
    Holes {
        path: PathBuf,
        count: usize,
        what: String,
        percent: f64,
        x: usize,
        y: usize,
    },
    #[error("depth map {path} has no depth at all: every value is a hole ({what})")]
    NoDepth { path: PathBuf, what: String },
    #[error("depth map {path} has all values equal ({value}); it carries no depth")]
    Constant { path: PathBuf, value: f32 },
    #[error(
        "depth map {path} has {count} values <= 0 (first at x={x}, y={y}); \
         depth must be positive (is it disparity? pass --depth-kind disparity)"
    )]
    NonPositive {
        path: PathBuf,
        count: usize,
        x: usize,
        y: usize,
    },
    #[error(
        "depth map {path} has {count} values outside {MIN_FILE_DEPTH:e} to {MAX_FILE_DEPTH:e} \
         units (first {value:e} at x={x}, y={y}); rescale it to a unit nearer the scene's"
    )]
    OutOfRange {
        path: PathBuf,
        count: usize,
        value: f32,
        x: usize,
        y: usize,
    },
    #[error(
        "depth map {path} is {depth_w}x{depth_h} but the photo is {photo_w}x{photo_h}: \
         aspect ratios {:.3} and {:.3} differ (rotated or cropped?)",
        *depth_w as f64 / *depth_h as f64, *photo_w as f64 / *photo_h as f64
    )]
    Aspect {
        path: PathBuf,
        depth_w: usize,
        depth_h: usize,
        photo_w: u32,
        photo_h: u32,
    },
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// How the numbers in a depth file are to be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthKind {
    /// Distance along the optical axis, in scene units.
    Depth,
    /// Relative disparity (larger = nearer), affine-ambiguous.
    Disparity,
}

impl crate::io::keyword::Keyword for DepthKind {
    const ALL: &'static [(Self, &'static str)] =
        &[(Self::Depth, "depth"), (Self::Disparity, "disparity")];
}

/// The mapping from relative disparity to scene depth: the robust near end of the scene
/// (the 98th disparity percentile) lands at `near`, the robust far end (2nd percentile)
/// at `near + budget`, linearly in disparity; values beyond are clamped to
/// [`near`/2, 10 × far] so that sky or a stray pixel cannot give infinite depth.
/// The defaults (1 and 4) are the training data's subject range; a depth file read with
/// `--depth-kind disparity` is mapped with them.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SceneScale {
    pub near: f32,
    pub budget: f32,
}

impl Default for SceneScale {
    fn default() -> Self {
        Self {
            near: crate::depth::NEAR,
            budget: crate::depth::FAR - crate::depth::NEAR,
        }
    }
}

impl SceneScale {
    pub fn check(&self) -> Result<(), ScaleError> {
        if !(self.near > 0.0 && self.near.is_finite()) {
            return Err(ScaleError::Near(self.near));
        }
        if !(self.budget > 0.0 && self.budget.is_finite()) {
            return Err(ScaleError::Budget(self.budget));
        }
        Ok(())
    }

    pub fn far(&self) -> f32 {
        self.near + self.budget
    }

    /// Scene depth from relative disparity; also returns the percentiles used.
    pub fn depth_from_disparity(
        &self,
        width: usize,
        height: usize,
        disparity: &[f32],
    ) -> (DepthMap, [f32; 2]) {
        let (mut lo, mut hi) = (percentile(disparity, 0.02), percentile(disparity, 0.98));
        if hi <= lo {
            lo = disparity.iter().copied().fold(f32::INFINITY, f32::min);
            hi = disparity.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
        let (d_far, d_near) = (1.0 / self.far(), 1.0 / self.near);
        let (d_min, d_max) = (1.0 / (10.0 * self.far()), 2.0 / self.near);
        let span = (hi - lo).max(f32::MIN_POSITIVE);
        let data = disparity
            .iter()
            .map(|&v| 1.0 / (d_far + (v - lo) / span * (d_near - d_far)).clamp(d_min, d_max))
            .collect();
        (DepthMap::new(width, height, data), [lo, hi])
    }
}

/// A [`SceneScale`] that cannot map disparity to depth.
#[derive(Debug, thiserror::Error)]
pub enum ScaleError {
    #[error("--near {0} must be a positive depth")]
    Near(f32),
    #[error("--depth-budget {0} must be positive")]
    Budget(f32),
}

/// Scene depth per pixel, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

/// The map as it was in the file, before interpretation.
#[derive(Clone, Debug, PartialEq)]
pub struct RawMap {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

/// What loading did to the file, for the log and run.json.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DepthReport {
    pub kind: DepthKind,
    pub file_size: [usize; 2],
    pub resized_to: Option<[usize; 2]>,
    /// Disparity percentiles (2nd, 98th) mapped to FAR and NEAR, for relative disparity.
    pub disparity_percentiles: Option<[f32; 2]>,
    pub depth_range: [f32; 2],
    /// `--depth-holes`, and the share of the file's pixels that were holes (0 to 1).
    pub hole_policy: HolePolicy,
    pub hole_fraction: f64,
}

impl DepthMap {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Self {
        assert_eq!(
            width * height,
            data.len(),
            "depth buffer does not match size"
        );
        Self {
            width,
            height,
            data,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn data(&self) -> &[f32] {
        &self.data
    }

    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Reads, validates and interprets a depth file, treats its holes as `holes` says
    /// (filling follows `photo`'s colours) and fits it to `photo`'s size.
    pub fn load(
        path: &Path,
        kind: DepthKind,
        holes: HolePolicy,
        photo: &SrgbImage,
    ) -> Result<(Self, DepthReport), DepthError> {
        let (photo_w, photo_h) = (photo.width(), photo.height());
        let mut raw = read_raw(path)?;
        check_aspect(path, &raw, photo_w, photo_h)?;
        let hole_fraction = treat_holes(path, &mut raw, kind, holes, photo)?;
        check_not_constant(path, &raw)?;
        let (map, percentiles) = match kind {
            DepthKind::Depth => (Self::from_depth(path, raw.clone())?, None),
            DepthKind::Disparity => {
                let (map, p) = Self::from_relative_disparity(&raw);
                (map, Some(p))
            }
        };
        let target = (photo_w as usize, photo_h as usize);
        let resized_to = (target != (map.width, map.height)).then(|| {
            log::info!(
                "depth map {} is {}x{}, resizing to the photo's {}x{}",
                path.display(),
                map.width,
                map.height,
                target.0,
                target.1
            );
            [target.0, target.1]
        });
        let map = map.resized(target.0, target.1);
        let report = DepthReport {
            kind,
            file_size: [raw.width, raw.height],
            resized_to,
            disparity_percentiles: percentiles,
            depth_range: map.range(),
            hole_policy: holes,
            hole_fraction,
        };
        Ok((map, report))
    }

    fn from_depth(path: &Path, raw: RawMap) -> Result<Self, DepthError> {
        let bad: Vec<usize> = (0..raw.values.len())
            .filter(|&i| raw.values[i] <= 0.0)
            .collect();
        if let Some(&first) = bad.first() {
            return Err(DepthError::NonPositive {
                path: path.into(),
                count: bad.len(),
                x: first % raw.width,
                y: first / raw.width,
            });
        }
        let outside: Vec<usize> = (0..raw.values.len())
            .filter(|&i| !(MIN_FILE_DEPTH..=MAX_FILE_DEPTH).contains(&raw.values[i]))
            .collect();
        if let Some(&first) = outside.first() {
            return Err(DepthError::OutOfRange {
                path: path.into(),
                count: outside.len(),
                value: raw.values[first],
                x: first % raw.width,
                y: first / raw.width,
            });
        }
        Ok(Self::new(raw.width, raw.height, raw.values))
    }

    /// Maps relative disparity with the default [`SceneScale`] (its 2nd/98th percentiles
    /// land at [`FAR`] and [`NEAR`]). Returns the percentiles used.
    pub fn from_relative_disparity(raw: &RawMap) -> (Self, [f32; 2]) {
        SceneScale::default().depth_from_disparity(raw.width, raw.height, &raw.values)
    }

    pub fn range(&self) -> [f32; 2] {
        let min = self.data.iter().copied().fold(f32::INFINITY, f32::min);
        let max = self.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        [min, max]
    }

    /// Depth at the given fraction (0..=1) of the sorted values.
    pub fn percentile(&self, q: f64) -> f32 {
        percentile(&self.data, q)
    }

    /// Bilinear resampling in disparity (1/depth), pixel centres aligned: interpolating
    /// depth itself would bias mixed pixels towards the background.
    pub fn resized(&self, width: usize, height: usize) -> Self {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        let sx = self.width as f32 / width as f32;
        let sy = self.height as f32 / height as f32;
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            let fy = ((y as f32 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f32);
            let (y0, ty) = (fy.floor() as usize, fy.fract());
            let y1 = (y0 + 1).min(self.height - 1);
            for x in 0..width {
                let fx = ((x as f32 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f32);
                let (x0, tx) = (fx.floor() as usize, fx.fract());
                let x1 = (x0 + 1).min(self.width - 1);
                let d = |x: usize, y: usize| 1.0 / self.at(x, y);
                let top = d(x0, y0) * (1.0 - tx) + d(x1, y0) * tx;
                let bottom = d(x0, y1) * (1.0 - tx) + d(x1, y1) * tx;
                data.push(1.0 / (top * (1.0 - ty) + bottom * ty));
            }
        }
        Self::new(width, height, data)
    }

    /// Scales every depth by `factor` (geometry is scale-covariant).
    pub fn scaled(&self, factor: f32) -> Self {
        Self::new(
            self.width,
            self.height,
            self.data.iter().map(|d| d * factor).collect(),
        )
    }
}

/// Refuses or fills the holes of `raw` as `policy` says; returns the share of pixels
/// that were holes.
fn treat_holes(
    path: &Path,
    raw: &mut RawMap,
    kind: DepthKind,
    policy: HolePolicy,
    photo: &SrgbImage,
) -> Result<f64, DepthError> {
    let holes = Holes::find(&raw.values, kind);
    let Some(first) = holes.first else {
        return Ok(0.0);
    };
    if holes.count() == raw.values.len() {
        return Err(DepthError::NoDepth {
            path: path.into(),
            what: holes.describe(),
        });
    }
    match policy {
        HolePolicy::Refuse => {
            return Err(DepthError::Holes {
                path: path.into(),
                count: holes.count(),
                what: holes.describe(),
                percent: holes.fraction() * 100.0,
                x: first % raw.width,
                y: first / raw.width,
            })
        }
        HolePolicy::Far => depth_holes::fill_far(&mut raw.values, &holes.mask, kind),
        HolePolicy::Fill => {
            let guide = photo.resized(raw.width as u32, raw.height as u32);
            depth_holes::fill_guided(
                &mut raw.values,
                &holes.mask,
                raw.width,
                raw.height,
                kind,
                &guide,
            );
        }
    }
    log::info!(
        "depth map {}: {} holes ({}, {:.2}% of the map), --depth-holes {}",
        path.display(),
        holes.count(),
        holes.describe(),
        holes.fraction() * 100.0,
        crate::io::keyword::Keyword::keyword(policy)
    );
    Ok(holes.fraction())
}

fn check_not_constant(path: &Path, raw: &RawMap) -> Result<(), DepthError> {
    let first = raw.values[0];
    if raw.values.iter().all(|&v| v == first) {
        return Err(DepthError::Constant {
            path: path.into(),
            value: first,
        });
    }
    Ok(())
}

fn check_aspect(path: &Path, raw: &RawMap, photo_w: u32, photo_h: u32) -> Result<(), DepthError> {
    let depth_aspect = raw.width as f64 / raw.height as f64;
    let photo_aspect = f64::from(photo_w) / f64::from(photo_h);
    if (depth_aspect / photo_aspect - 1.0).abs() > ASPECT_TOLERANCE {
        return Err(DepthError::Aspect {
            path: path.into(),
            depth_w: raw.width,
            depth_h: raw.height,
            photo_w,
            photo_h,
        });
    }
    Ok(())
}

/// The value at quantile `q` (0 to 1, nearest rank) of `values`, which must not be empty.
pub(crate) fn percentile(values: &[f32], q: f64) -> f32 {
    let mut sorted = values.to_vec();
    let k = ((sorted.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    let (_, v, _) = sorted.select_nth_unstable_by(k, f32::total_cmp);
    *v
}

#[cfg(test)]
mod tests;
