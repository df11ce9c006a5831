//! The depth network stage: a monocular depth model described by its manifest, run by an
//! [`Engine`], and the mapping of its relative output to scene depth.
//!
//! The manifest's `depth` object says how to feed the model and read its output:
//!
//! - `input_size.policy`: `"longest-side"` (the longer side becomes `size`, the other keeps
//!   the aspect ratio, truncated; then each side is rounded down to `multiple`), `"fixed"`
//!   (`size` is N for N×N or `[height, width]`; the photo is stretched), or `"multiple"`
//!   (the photo's own size, shrunk so the longer side is at most `size` when given, each
//!   side rounded to the nearest `multiple`).
//! - `resize`: `"area"` (OpenCV `INTER_AREA` reproduced bit for bit; the shipped
//!   Tiefenrausch model needs exactly this) or `"bilinear"`.
//! - `output_kind`: `"log-disparity"` (disparity = exp), `"disparity"` (relative, larger
//!   is nearer) or `"depth"` (metric, in the model's units).
//!
//! The manifest's `image` object gives the value range ([0, 1] or [0, 255]), the channel
//! order (`rgb`/`bgr`) and an optional per-channel mean/std. A model that normalises
//! inside its graph must say `mean: null` — the runtime would otherwise normalise twice.

pub mod cli;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use image::imageops::FilterType;
use image::RgbImage;
use serde::Deserialize;

use crate::depth::embedded::{self as embedded_depth, Container, EmbeddedDepth, RangeFormat};
use crate::depth::refine::{self as depth_refine, RefineOptions};
use crate::depth::{DepthMap, RawMap};
use crate::engine::manifest::{self, Manifest, ManifestError, Precision, Task, VerifiedModel};
use crate::engine::{Engine, EngineError, ModelSource, Plan, Tensor};
use crate::io::record::{FileRecord, Timings};
use crate::reshade::net::resample;

/// Where the shipped depth models live, relative to the working directory or the source
/// tree the binary was built from.
pub const DEFAULT_MODEL_DIR: &str = "models/depth";
/// The shipped model's file stem; the precision is appended (`tiefenrausch-int8`).
pub const DEFAULT_MODEL: &str = "tiefenrausch";
/// Largest network input side accepted from a manifest: beyond it a typo, not a model.
const MAX_INPUT_SIDE: usize = 4096;

#[derive(Debug, thiserror::Error)]
pub enum DepthNetError {
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Engine(#[from] EngineError),
    #[error("depth model {path}: {problem}")]
    Model { path: PathBuf, problem: String },
    #[error("depth model {path}: photo {width}x{height} cannot be fed to it: {problem}")]
    Photo {
        path: PathBuf,
        width: u32,
        height: u32,
        problem: String,
    },
    #[error("{0}")]
    Embedded(String),
    #[error(
        "no depth model found: looked for {tried}; pass --depth-model FILE (an .onnx with its \
         .json manifest beside it, or the manifest) or --depth FILE"
    )]
    NotFound { tried: String },
}

/// How the network's input size follows from the photo's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "policy")]
pub enum SizePolicy {
    LongestSide {
        size: usize,
        multiple: usize,
    },
    Fixed {
        width: usize,
        height: usize,
    },
    Multiple {
        max_side: Option<usize>,
        multiple: usize,
    },
}

/// In words, for messages: "an input whose longest side is 384 px (sides multiples of 32)".
impl std::fmt::Display for SizePolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            SizePolicy::LongestSide { size, multiple } => write!(
                f,
                "an input whose longest side is {size} px (sides multiples of {multiple})"
            ),
            SizePolicy::Fixed { width, height } => write!(f, "a fixed {width}x{height} input"),
            SizePolicy::Multiple {
                max_side: Some(max),
                multiple,
            } => write!(
                f,
                "an input with sides multiples of {multiple}, at most {max} px"
            ),
            SizePolicy::Multiple {
                max_side: None,
                multiple,
            } => write!(f, "an input with sides multiples of {multiple}"),
        }
    }
}

impl SizePolicy {
    /// The network's input (width, height) for a photo of `width`×`height`.
    pub fn network_size(&self, width: usize, height: usize) -> Option<(usize, usize)> {
        if width == 0 || height == 0 {
            return None;
        }
        let (w, h) = match *self {
            SizePolicy::Fixed { width, height } => return Some((width, height)),
            SizePolicy::LongestSide { size, multiple } => {
                let (w, h) = if height > width {
                    (width * size / height, size)
                } else {
                    (size, height * size / width)
                };
                (w - w % multiple, h - h % multiple)
            }
            SizePolicy::Multiple { max_side, multiple } => {
                let long = width.max(height);
                let k = max_side.map_or(1.0, |m| (m as f64 / long as f64).min(1.0));
                let round = |v: usize| {
                    let scaled = v as f64 * k / multiple as f64;
                    (scaled.round() as usize).max(1) * multiple
                };
                (round(width), round(height))
            }
        };
        (w > 0 && h > 0).then_some((w, h))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ResizeMethod {
    Area,
    Bilinear,
}

/// What the model's output means.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OutputKind {
    LogDisparity,
    Disparity,
    Depth,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Layout {
    Nchw,
    Nhwc,
}

/// Everything the runtime needs to feed a depth model and read its answer, checked.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DepthSpec {
    pub input: String,
    pub output: String,
    pub size: SizePolicy,
    pub resize: ResizeMethod,
    /// 1 for inputs in [0, 1], 255 for [0, 255].
    pub value_max: f32,
    pub bgr: bool,
    pub mean: Option<[f32; 3]>,
    pub std: Option<[f32; 3]>,
    pub output_kind: OutputKind,
    #[serde(skip)]
    layout: Layout,
}

#[derive(Deserialize)]
struct RawDepthField {
    input_size: RawInputSize,
    #[serde(default)]
    resize: Option<String>,
    output_kind: String,
}

#[derive(Deserialize)]
struct RawInputSize {
    policy: String,
    #[serde(default)]
    size: Option<serde_json::Value>,
    #[serde(default)]
    multiple: Option<usize>,
}

impl DepthSpec {
    /// Reads and checks the depth-specific parts of a manifest (`path` names it in errors).
    pub fn from_manifest(path: &Path, m: &Manifest) -> Result<Self, ManifestError> {
        let err = |field: &str, problem: String| manifest::field_error(path, field, problem);
        if m.task != Task::Depth {
            return Err(err(
                "task",
                format!("is {:?}; a depth model is needed", m.task.to_string()),
            ));
        }
        let [input] = m.inputs.as_slice() else {
            return Err(err(
                "inputs",
                format!(
                    "has {} tensors; a depth model takes one image",
                    m.inputs.len()
                ),
            ));
        };
        let [output] = m.outputs.as_slice() else {
            return Err(err(
                "outputs",
                format!(
                    "has {} tensors; a depth model gives one map",
                    m.outputs.len()
                ),
            ));
        };
        check_dtype(path, "inputs[0]", &input.dtype)?;
        check_dtype(path, "outputs[0]", &output.dtype)?;
        let layout = match input.layout.as_str() {
            "NCHW" => Layout::Nchw,
            "NHWC" => Layout::Nhwc,
            other => {
                return Err(err(
                    "inputs[0].layout",
                    format!("is {other:?}; expected \"NCHW\" or \"NHWC\""),
                ))
            }
        };
        let depth = m
            .depth
            .clone()
            .ok_or_else(|| err("depth", "is missing".into()))?;
        let raw: RawDepthField = serde_json::from_value(depth)
            .map_err(|e| err("depth", format!("is malformed: {e}")))?;
        let image = m
            .image
            .as_ref()
            .ok_or_else(|| err("image", "is missing".into()))?;
        let value_max = match image.range {
            [lo, hi] if lo == 0.0 && hi == 1.0 => 1.0,
            [lo, hi] if lo == 0.0 && hi == 255.0 => 255.0,
            r => {
                return Err(err(
                    "image.range",
                    format!("is {r:?}; expected [0, 1] or [0, 255]"),
                ))
            }
        };
        let bgr = match image.channel_order.as_str() {
            "rgb" => false,
            "bgr" => true,
            o => {
                return Err(err(
                    "image.channel_order",
                    format!("is {o:?}; expected \"rgb\" or \"bgr\""),
                ))
            }
        };
        let mean = triple(path, "image.mean", image.mean.as_deref())?;
        let std = triple(path, "image.std", image.std.as_deref())?;
        if std.is_some_and(|s| s.iter().any(|&v| !(v > 0.0 && v.is_finite()))) {
            return Err(err("image.std", "must be positive".into()));
        }
        Ok(Self {
            input: input.name.clone(),
            output: output.name.clone(),
            size: size_policy(path, &raw.input_size)?,
            resize: match raw.resize.as_deref() {
                None | Some("bilinear") => ResizeMethod::Bilinear,
                Some("area") => ResizeMethod::Area,
                Some(o) => {
                    return Err(err(
                        "depth.resize",
                        format!("is {o:?}; expected \"area\" or \"bilinear\""),
                    ))
                }
            },
            value_max,
            bgr,
            mean,
            std,
            output_kind: match raw.output_kind.as_str() {
                "log-disparity" => OutputKind::LogDisparity,
                "disparity" => OutputKind::Disparity,
                "depth" => OutputKind::Depth,
                o => {
                    return Err(err(
                        "depth.output_kind",
                        format!("is {o:?}; expected \"log-disparity\", \"disparity\" or \"depth\""),
                    ))
                }
            },
            layout,
        })
    }

    /// The network's input tensor for a uint8 RGB photo.
    pub fn input_tensor(&self, rgb: &RgbImage, (w, h): (usize, usize)) -> Tensor {
        let small = self.resize_photo(rgb, w, h);
        let px = small.as_raw();
        let mut data = vec![0.0f32; 3 * w * h];
        for c in 0..3 {
            let src_c = if self.bgr { 2 - c } else { c };
            let (m, s) = (
                self.mean.map_or(0.0, |m| m[c]),
                self.std.map_or(1.0, |s| s[c]),
            );
            for i in 0..w * h {
                let byte = f32::from(px[3 * i + src_c]);
                // Divide by 255 (not multiply by 1/255) as the reference does: the network
                // notices one-ulp input differences.
                let v = if self.value_max == 1.0 {
                    byte / 255.0
                } else {
                    byte
                };
                let at = match self.layout {
                    Layout::Nchw => c * w * h + i,
                    Layout::Nhwc => 3 * i + c,
                };
                data[at] = (v - m) / s;
            }
        }
        let shape = match self.layout {
            Layout::Nchw => vec![1, 3, h, w],
            Layout::Nhwc => vec![1, h, w, 3],
        };
        Tensor::new(shape, data)
    }

    fn resize_photo(&self, rgb: &RgbImage, w: usize, h: usize) -> RgbImage {
        let (pw, ph) = (rgb.width() as usize, rgb.height() as usize);
        if (pw, ph) == (w, h) {
            return rgb.clone();
        }
        if self.resize == ResizeMethod::Area && w <= pw && h <= ph {
            area_resize(rgb, w, h)
        } else {
            image::imageops::resize(rgb, w as u32, h as u32, FilterType::Triangle)
        }
    }

    /// Reads the output tensor as disparity (relative or from metric depth) or depth.
    fn read_output(&self, path: &Path, out: &Tensor) -> Result<NetworkDepth, DepthNetError> {
        let n = out.shape.len();
        let leading: usize = out.shape[..n.saturating_sub(2)].iter().product();
        if n < 2 || leading != 1 {
            return Err(DepthNetError::Model {
                path: path.into(),
                problem: format!(
                    "output {:?} has shape {:?}; expected one map [1, 1, H, W]",
                    self.output, out.shape
                ),
            });
        }
        let (h, w) = (out.shape[n - 2], out.shape[n - 1]);
        let values: Vec<f32> = match self.output_kind {
            OutputKind::LogDisparity => out.data.iter().map(|v| v.exp()).collect(),
            OutputKind::Disparity | OutputKind::Depth => out.data.clone(),
        };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(DepthNetError::Model {
                path: path.into(),
                problem: format!("output has a non-finite value at x={}, y={}", i % w, i / w),
            });
        }
        let positive = values.iter().filter(|&&v| v > 0.0).count();
        if self.output_kind == OutputKind::Depth && positive == 0 {
            return Err(DepthNetError::Model {
                path: path.into(),
                problem: "output kind is depth but no output value is positive".into(),
            });
        }
        Ok(NetworkDepth {
            kind: self.output_kind,
            map: RawMap {
                width: w,
                height: h,
                values,
            },
        })
    }
}

fn check_dtype(path: &Path, field: &str, dtype: &str) -> Result<(), ManifestError> {
    if dtype == "float32" {
        return Ok(());
    }
    Err(manifest::field_error(
        path,
        &format!("{field}.dtype"),
        format!("is {dtype:?}; the runtime exchanges float32"),
    ))
}

fn triple(path: &Path, field: &str, v: Option<&[f64]>) -> Result<Option<[f32; 3]>, ManifestError> {
    match v {
        None => Ok(None),
        Some([a, b, c]) => Ok(Some([*a as f32, *b as f32, *c as f32])),
        Some(other) => Err(manifest::field_error(
            path,
            field,
            format!(
                "has {} values; expected 3 (one per channel) or null",
                other.len()
            ),
        )),
    }
}

fn size_policy(path: &Path, raw: &RawInputSize) -> Result<SizePolicy, ManifestError> {
    let err = |field: &str, problem: String| manifest::field_error(path, field, problem);
    let side = |v: u64| -> Result<usize, ManifestError> {
        let v = v as usize;
        if v == 0 || v > MAX_INPUT_SIDE {
            return Err(err(
                "depth.input_size.size",
                format!("{v} is outside 1..={MAX_INPUT_SIDE}"),
            ));
        }
        Ok(v)
    };
    let multiple = raw.multiple.unwrap_or(1);
    if multiple == 0 || multiple > 256 {
        return Err(err(
            "depth.input_size.multiple",
            format!("is {multiple}; expected 1..=256"),
        ));
    }
    let size = raw.size.as_ref();
    let scalar = size.and_then(serde_json::Value::as_u64);
    match raw.policy.as_str() {
        "longest-side" => {
            let size = scalar.ok_or_else(|| {
                err(
                    "depth.input_size.size",
                    "must be a number for longest-side".into(),
                )
            })?;
            Ok(SizePolicy::LongestSide {
                size: side(size)?,
                multiple,
            })
        }
        "fixed" => {
            let (h, w) = match (scalar, size.and_then(serde_json::Value::as_array)) {
                (Some(s), _) => (s, s),
                (None, Some(a)) if a.len() == 2 && a.iter().all(|v| v.as_u64().is_some()) => {
                    (a[0].as_u64().unwrap_or(0), a[1].as_u64().unwrap_or(0))
                }
                _ => {
                    return Err(err(
                        "depth.input_size.size",
                        "must be N or [height, width] for fixed".into(),
                    ))
                }
            };
            Ok(SizePolicy::Fixed {
                width: side(w)?,
                height: side(h)?,
            })
        }
        "multiple" => Ok(SizePolicy::Multiple {
            max_side: scalar.map(side).transpose()?,
            multiple,
        }),
        o => Err(err(
            "depth.input_size.policy",
            format!("is {o:?}; expected \"longest-side\", \"fixed\" or \"multiple\""),
        )),
    }
}

/// The network's answer at its own resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkDepth {
    pub kind: OutputKind,
    /// Disparity (`exp` already applied for log-disparity) or metric depth.
    pub map: RawMap,
}

impl NetworkDepth {
    /// Disparity per pixel: relative for the disparity kinds, 1/depth for metric depth
    /// (non-positive depths, a model's "invalid", become the smallest valid disparity).
    pub fn disparity(&self) -> Vec<f32> {
        if self.kind != OutputKind::Depth {
            return self.map.values.clone();
        }
        let inv: Vec<f32> = self
            .map
            .values
            .iter()
            .map(|&z| if z > 0.0 { 1.0 / z } else { f32::NAN })
            .collect();
        let min = inv
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(f32::INFINITY, f32::min);
        inv.into_iter()
            .map(|v| if v.is_finite() { v } else { min })
            .collect()
    }
}

/// A depth model loaded from its manifest, with one engine plan per input size.
pub struct DepthNet {
    model: VerifiedModel,
    spec: DepthSpec,
    engine: Arc<dyn Engine>,
    plans: Mutex<HashMap<(usize, usize), Arc<dyn Plan>>>,
}

impl DepthNet {
    /// Loads a depth model from its manifest (.json) or from the .onnx file with the
    /// manifest of the same stem beside it.
    pub fn load(path: &Path, engine: Arc<dyn Engine>) -> Result<Self, DepthNetError> {
        let manifest_path = manifest_path_for(path)?;
        let model = manifest::load_verified(&manifest_path)?;
        let spec = DepthSpec::from_manifest(&manifest_path, &model.manifest)?;
        Ok(Self {
            model,
            spec,
            engine,
            plans: Mutex::new(HashMap::new()),
        })
    }

    /// The shipped model at `precision`, found under [`DEFAULT_MODEL_DIR`] in the working
    /// directory, `$RESHADER_DEPTH_MODELS`, or the source tree.
    pub fn shipped(precision: Precision, engine: Arc<dyn Engine>) -> Result<Self, DepthNetError> {
        let file = format!("{DEFAULT_MODEL}-{precision}.json");
        let mut dirs = vec![PathBuf::from(DEFAULT_MODEL_DIR)];
        if let Some(dir) = std::env::var_os("RESHADER_DEPTH_MODELS") {
            dirs.insert(0, PathBuf::from(dir));
        }
        dirs.push(Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_MODEL_DIR));
        let candidates: Vec<PathBuf> = dirs.iter().map(|d| d.join(&file)).collect();
        match candidates.iter().find(|p| p.is_file()) {
            Some(p) => Self::load(p, engine),
            None => Err(DepthNetError::NotFound {
                tried: candidates
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
            }),
        }
    }

    pub fn spec(&self) -> &DepthSpec {
        &self.spec
    }

    pub fn manifest(&self) -> &Manifest {
        &self.model.manifest
    }

    pub fn manifest_path(&self) -> &Path {
        &self.model.manifest_path
    }

    pub fn engine(&self) -> &dyn Engine {
        self.engine.as_ref()
    }

    /// The network's input (width, height) for a photo of `width`×`height`.
    pub fn network_size(&self, width: u32, height: u32) -> Result<(usize, usize), DepthNetError> {
        self.spec
            .size
            .network_size(width as usize, height as usize)
            .ok_or_else(|| DepthNetError::Photo {
                path: self.model.model_path.clone(),
                width,
                height,
                problem: format!(
                    "too small or too elongated for the depth network, which takes {}",
                    self.spec.size
                ),
            })
    }

    /// Runs the network on a uint8 RGB photo; the result is at the network's resolution.
    pub fn estimate(&self, rgb: &RgbImage) -> Result<NetworkDepth, DepthNetError> {
        let size = self.network_size(rgb.width(), rgb.height())?;
        let input = self.spec.input_tensor(rgb, size);
        let plan = self.plan(size, &input.shape)?;
        let outputs = plan.run(&[(self.spec.input.as_str(), &input)])?;
        let out = outputs.first().ok_or_else(|| DepthNetError::Model {
            path: self.model.model_path.clone(),
            problem: "the engine returned no output".into(),
        })?;
        self.spec.read_output(&self.model.model_path, out)
    }

    fn plan(&self, size: (usize, usize), shape: &[usize]) -> Result<Arc<dyn Plan>, DepthNetError> {
        let mut plans = self.plans.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(plan) = plans.get(&size) {
            return Ok(plan.clone());
        }
        let started = std::time::Instant::now();
        let plan = self.engine.plan(
            ModelSource {
                path: &self.model.model_path,
                bytes: &self.model.bytes,
                precision: self.model.manifest.precision,
            },
            &[(self.spec.input.as_str(), shape.to_vec())],
            &[self.spec.output.as_str()],
        )?;
        log::info!(
            "{}: {} plan for {}x{} ready in {:.0} ms",
            self.model.manifest.name,
            self.engine.name(),
            size.0,
            size.1,
            started.elapsed().as_secs_f64() * 1e3
        );
        plans.insert(size, plan.clone());
        Ok(plan)
    }
}

/// `FILE.json` as given, or the manifest of the same stem beside `FILE.onnx`.
fn manifest_path_for(path: &Path) -> Result<PathBuf, DepthNetError> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return Ok(path.to_owned());
    }
    let manifest = path.with_extension("json");
    if manifest.is_file() {
        return Ok(manifest);
    }
    Err(DepthNetError::Model {
        path: path.to_owned(),
        problem: format!(
            "has no manifest {} beside it: write one (notes: depth-readme.md) saying how to \
             feed the model and what its output means",
            manifest.display()
        ),
    })
}

/// Area-averages a uint8 RGB image down to `w`×`h`, rounding back to uint8 the way
/// OpenCV's `INTER_AREA` does: the network is sensitive to one-level input changes, so
/// the reference numbers are only reproduced with the same float32 sums in the same order.
pub fn area_resize(img: &RgbImage, w: usize, h: usize) -> RgbImage {
    let (sw, sh) = (img.width() as usize, img.height() as usize);
    assert!(
        w > 0 && h > 0 && w <= sw && h <= sh,
        "area resize only shrinks"
    );
    let data = if sw % w == 0 && sh % h == 0 {
        block_mean(img.as_raw(), sw, sw / w, sh / h, w, h)
    } else {
        separable_area(img.as_raw(), sw, sh, w, h)
    };
    RgbImage::from_raw(w as u32, h as u32, data).expect("buffer matches size")
}

/// Whole-number shrink factors: exact integer block sums, rounded as OpenCV's fast path.
fn block_mean(src: &[u8], sw: usize, fx: usize, fy: usize, w: usize, h: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(w * h * 3);
    let inv = 1.0f32 / (fx * fy) as f32;
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut sum = 0u32;
                for yy in y * fy..(y + 1) * fy {
                    for xx in x * fx..(x + 1) * fx {
                        sum += u32::from(src[(yy * sw + xx) * 3 + c]);
                    }
                }
                out.push(if fx * fy == 4 {
                    ((sum + 2) >> 2) as u8
                } else {
                    (sum as f32 * inv).round_ties_even().clamp(0.0, 255.0) as u8
                });
            }
        }
    }
    out
}

/// Source indices and float32 weights of the source interval each output pixel covers;
/// partial overlaps under 1e-3 of a pixel are dropped, as OpenCV does.
fn area_taps(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|d| {
            let (lo, hi) = (d as f64 * scale, (d + 1) as f64 * scale);
            let (first, last) = (lo.ceil() as usize, hi.floor() as usize);
            let mut taps = Vec::new();
            if first as f64 - lo > 1e-3 {
                taps.push((first - 1, ((first as f64 - lo) / scale) as f32));
            }
            taps.extend((first..last).map(|s| (s, (1.0 / scale) as f32)));
            if hi - last as f64 > 1e-3 && last < src {
                taps.push((last, ((hi - last as f64) / scale) as f32));
            }
            taps
        })
        .collect()
}

/// General shrink factors: each source row is shrunk horizontally, then the rows are
/// combined, both in float32 with the taps summed in source order.
fn separable_area(src: &[u8], sw: usize, sh: usize, w: usize, h: usize) -> Vec<u8> {
    let xt = area_taps(sw, w);
    let yt = area_taps(sh, h);
    let mut rows = vec![0.0f32; sh * w * 3];
    for y in 0..sh {
        for (x, taps) in xt.iter().enumerate() {
            for c in 0..3 {
                let mut acc = 0.0f32;
                for &(s, wt) in taps {
                    acc += f32::from(src[(y * sw + s) * 3 + c]) * wt;
                }
                rows[(y * w + x) * 3 + c] = acc;
            }
        }
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for taps in &yt {
        for i in 0..w * 3 {
            let mut acc = 0.0f32;
            for &(s, wt) in taps {
                acc += wt * rows[s * w * 3 + i];
            }
            out.push(acc.round_ties_even().clamp(0.0, 255.0) as u8);
        }
    }
    out
}

/// The mapping from relative disparity to scene depth: the robust near end of the scene
/// (the 98th disparity percentile) lands at `near`, the robust far end (2nd percentile)
/// at `near + budget`, linearly in disparity; values beyond are clamped to
/// [`near`/2, 10 × far] so that sky or a stray pixel cannot give infinite depth.
/// With the defaults (1 and 4) this is the spine's `--depth-kind disparity` mapping.
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
    pub fn check(&self) -> Result<(), String> {
        if !(self.near > 0.0 && self.near.is_finite()) {
            return Err(format!("--near {} must be a positive depth", self.near));
        }
        if !(self.budget > 0.0 && self.budget.is_finite()) {
            return Err(format!("--depth-budget {} must be positive", self.budget));
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

/// Settings of the depth stage that do not depend on where the depth comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageOptions {
    pub scale: SceneScale,
    /// Edge refinement after upsampling (None: off). A radius of 0 means "from the
    /// upsampling factor".
    pub refine: Option<RefineOptions>,
}

impl Default for StageOptions {
    fn default() -> Self {
        Self {
            scale: SceneScale::default(),
            refine: Some(RefineOptions::default()),
        }
    }
}

/// What the depth stage did, for the log and run.json.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StageReport {
    /// "network" or "embedded".
    pub source: &'static str,
    pub model: Option<String>,
    /// The network's ONNX file and its sha256 (verified against the manifest at load).
    pub model_file: Option<FileRecord>,
    pub precision: Option<Precision>,
    pub engine: Option<String>,
    pub output_kind: OutputKind,
    /// Size the depth had before upsampling (network input or embedded image).
    pub native_size: [usize; 2],
    pub embedded: Option<EmbeddedReport>,
    /// Why embedded depth present in the photo was not used.
    pub embedded_error: Option<String>,
    /// Relative disparity only: the percentiles mapped to near and far.
    pub disparity_percentiles: Option<[f32; 2]>,
    pub scene_scale: Option<SceneScale>,
    pub refine: Option<RefineOptions>,
    pub depth_range: [f32; 2],
    pub time_ms: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct EmbeddedReport {
    pub container: Container,
    pub format: RangeFormat,
    pub near: f32,
    pub far: f32,
    pub units: Option<String>,
    pub mime: String,
}

/// Scene depth for a photo from the network: estimate at the network's size, upsample
/// the disparity to the photo, refine its edges with the photo, map it to scene depth
/// (relative outputs through `opts.scale`; metric depth keeps its units).
pub fn network_depth(
    net: &DepthNet,
    photo: &RgbImage,
    opts: &StageOptions,
) -> Result<(DepthMap, StageReport), DepthNetError> {
    let started = std::time::Instant::now();
    let estimate = net.estimate(photo)?;
    let native = [estimate.map.width, estimate.map.height];
    let (map, percentiles, refine) =
        finish(&estimate.disparity(), native, estimate.kind, photo, opts);
    let m = net.manifest();
    let report = StageReport {
        source: "network",
        model: Some(format!("{} {}", m.name, m.version)),
        model_file: Some(FileRecord {
            path: net.model.model_path.display().to_string(),
            sha256: m.sha256.trim().to_ascii_lowercase(),
        }),
        precision: Some(m.precision),
        engine: Some(format!(
            "{} x{} threads",
            net.engine().name(),
            net.engine().threads()
        )),
        output_kind: estimate.kind,
        native_size: native,
        embedded: None,
        embedded_error: None,
        disparity_percentiles: percentiles,
        scene_scale: percentiles.map(|_| opts.scale),
        refine,
        depth_range: map.range(),
        time_ms: started.elapsed().as_secs_f64() * 1e3,
    };
    Ok((map, report))
}

/// Scene depth from depth the photo carries (metric, kept in its units), upright as the
/// photo is shown, fitted to the photo and refined like the network's.
pub fn embedded_scene_depth(
    found: &EmbeddedDepth,
    photo: &RgbImage,
    opts: &StageOptions,
) -> Result<(DepthMap, StageReport), String> {
    let started = std::time::Instant::now();
    let upright = embedded_depth::apply_orientation(&found.map, found.orientation);
    let (dw, dh) = (upright.width as f64, upright.height as f64);
    let photo_aspect = f64::from(photo.width()) / f64::from(photo.height());
    if ((dw / dh) / photo_aspect - 1.0).abs() > crate::depth::ASPECT_TOLERANCE {
        return Err(format!(
            "embedded depth is {}x{} but the photo is {}x{}: aspect ratios differ",
            upright.width,
            upright.height,
            photo.width(),
            photo.height()
        ));
    }
    let disparity: Vec<f32> = upright.values.iter().map(|&z| 1.0 / z).collect();
    let native = [upright.width, upright.height];
    let (map, _, refine) = finish(&disparity, native, OutputKind::Depth, photo, opts);
    let report = StageReport {
        source: "embedded",
        model: None,
        model_file: None,
        precision: None,
        engine: None,
        output_kind: OutputKind::Depth,
        native_size: native,
        embedded: Some(EmbeddedReport {
            container: found.container,
            format: found.format,
            near: found.near,
            far: found.far,
            units: found.units.clone(),
            mime: found.mime.clone(),
        }),
        embedded_error: None,
        disparity_percentiles: None,
        scene_scale: None,
        refine,
        depth_range: map.range(),
        time_ms: started.elapsed().as_secs_f64() * 1e3,
    };
    Ok((map, report))
}

type Finished = (DepthMap, Option<[f32; 2]>, Option<RefineOptions>);

/// Upsamples disparity to the photo (refining it on the way) and converts it to depth.
fn finish(
    disparity: &[f32],
    [w, h]: [usize; 2],
    kind: OutputKind,
    photo: &RgbImage,
    opts: &StageOptions,
) -> Finished {
    let (pw, ph) = (photo.width() as usize, photo.height() as usize);
    let (up, refine) = match opts.refine {
        Some(r) => {
            let (up, r) = refined(disparity, (w, h), photo, r);
            (up, Some(r))
        }
        None => (resample::resize(disparity, w, h, pw, ph), None),
    };
    if kind == OutputKind::Depth {
        let data = up.iter().map(|&d| 1.0 / d.max(f32::MIN_POSITIVE)).collect();
        return (DepthMap::new(pw, ph, data), None, refine);
    }
    let (map, p) = opts.scale.depth_from_disparity(pw, ph, &up);
    (map, Some(p), refine)
}

/// Refines at a working size of at most `max_side` (the median's cost is per pixel),
/// then upsamples to the photo: the remaining blur is at most photo/working pixels.
fn refined(
    disparity: &[f32],
    (w, h): (usize, usize),
    photo: &RgbImage,
    r: RefineOptions,
) -> (Vec<f32>, RefineOptions) {
    let (pw, ph) = (photo.width() as usize, photo.height() as usize);
    let k = (r.max_side.max(1) as f64 / pw.max(ph) as f64).min(1.0);
    let (ww, wh) = (
        ((pw as f64 * k).round() as usize).max(1),
        ((ph as f64 * k).round() as usize).max(1),
    );
    let guide = if (ww, wh) == (pw, ph) {
        photo.clone()
    } else {
        image::imageops::resize(photo, ww as u32, wh as u32, FilterType::Triangle)
    };
    let rgb: Vec<f32> = guide
        .as_raw()
        .iter()
        .map(|&v| f32::from(v) / 255.0)
        .collect();
    let r = match r.radius {
        0 => RefineOptions {
            radius: RefineOptions::radius_for(w.max(h), ww.max(wh)),
            ..r
        },
        _ => r,
    };
    let work = resample::resize(disparity, w, h, ww, wh);
    let work = depth_refine::refine_disparity(&rgb, &work, ww, wh, r);
    (resample::resize(&work, ww, wh, pw, ph), r)
}

/// Where the depth of a photo comes from when no depth file is given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum DepthSource {
    /// Depth embedded in the photo if it has any, else the network.
    Auto,
    Network,
    Embedded,
}

/// Which depth network to use and how to run it.
#[derive(Clone, Debug, PartialEq)]
pub struct NetChoice {
    /// A manifest or an .onnx with its manifest beside it (None: the shipped model).
    pub model: Option<PathBuf>,
    /// Precision of the shipped model (ignored with `model`).
    pub precision: Precision,
    pub engine: String,
    pub threads: usize,
}

impl NetChoice {
    pub fn load(&self) -> Result<DepthNet, DepthNetError> {
        let engine = crate::engine::by_name(&self.engine, self.threads)?;
        match &self.model {
            Some(path) => DepthNet::load(path, engine),
            None => DepthNet::shipped(self.precision, engine),
        }
    }
}

/// Depth for photos that come without a depth file: where to take it from, the network
/// (loaded on first use and kept, so a batch or a camera stream loads it once), and the
/// stage options.
pub struct DepthEstimator {
    source: DepthSource,
    choice: NetChoice,
    opts: StageOptions,
    net: Mutex<Option<Arc<DepthNet>>>,
}

impl DepthEstimator {
    pub fn new(source: DepthSource, choice: NetChoice, opts: StageOptions) -> Self {
        Self {
            source,
            choice,
            opts,
            net: Mutex::new(None),
        }
    }

    pub fn source(&self) -> DepthSource {
        self.source
    }

    pub fn options(&self) -> &StageOptions {
        &self.opts
    }

    /// The network, loading it on the first call; a failed load is retried next time.
    pub fn net(&self) -> Result<Arc<DepthNet>, DepthNetError> {
        let mut slot = self.net.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(net) = slot.as_ref() {
            return Ok(Arc::clone(net));
        }
        let started = std::time::Instant::now();
        let net = Arc::new(self.choice.load()?);
        log::info!(
            "depth model {} loaded in {:.0} ms",
            net.model.model_path.display(),
            started.elapsed().as_secs_f64() * 1e3
        );
        *slot = Some(Arc::clone(&net));
        Ok(net)
    }

    /// The network; `load_ms` gets the loading time when this call loaded it.
    fn loaded_net(&self, load_ms: &mut f64) -> Result<Arc<DepthNet>, DepthNetError> {
        if let Some(net) = self.net.lock().unwrap_or_else(|p| p.into_inner()).as_ref() {
            return Ok(Arc::clone(net));
        }
        let started = std::time::Instant::now();
        let net = self.net()?;
        *load_ms = started.elapsed().as_secs_f64() * 1e3;
        Ok(net)
    }

    /// Everything that changes the estimated depth, for the gallery's fingerprint.
    pub fn describe(&self) -> String {
        let model = match &self.choice.model {
            Some(path) => path.display().to_string(),
            None => format!("{DEFAULT_MODEL}-{}", self.choice.precision),
        };
        format!(
            "depth {:?} model {model} near {} budget {} refine {:?}",
            self.source, self.opts.scale.near, self.opts.scale.budget, self.opts.refine
        )
    }

    /// Scene depth for the photo at `photo_path` (decoded upright as `photo`). In `Auto`,
    /// unreadable embedded depth is logged and recorded in the report, and the network is
    /// used instead; asked for explicitly, it is an error.
    ///
    /// Loading the network (first use only) is timed in `t` as `depth_model`; the
    /// report's `time_ms` is the rest of the stage, and `t` gets it as `depth`.
    pub fn depth(
        &self,
        photo_path: &Path,
        photo: &RgbImage,
        t: &mut Timings,
    ) -> Result<(DepthMap, StageReport), DepthNetError> {
        let started = std::time::Instant::now();
        let mut load_ms = 0.0;
        let (map, mut report) = self.find(photo_path, photo, &mut load_ms)?;
        report.time_ms = started.elapsed().as_secs_f64() * 1e3 - load_ms;
        if load_ms > 0.0 {
            t.add("depth_model", load_ms);
        }
        t.add("depth", report.time_ms);
        Ok((map, report))
    }

    fn find(
        &self,
        photo_path: &Path,
        photo: &RgbImage,
        load_ms: &mut f64,
    ) -> Result<(DepthMap, StageReport), DepthNetError> {
        let mut embedded_error = None;
        if self.source != DepthSource::Network {
            match (self.embedded(photo_path, photo), self.source) {
                (Ok(Some(result)), _) => {
                    log::info!(
                        "{}: using the depth embedded in the photo",
                        photo_path.display()
                    );
                    return Ok(result);
                }
                (Ok(None), DepthSource::Embedded) => {
                    return Err(DepthNetError::Embedded(format!(
                        "{} carries no embedded depth (GDepth or Dynamic Depth)",
                        photo_path.display()
                    )))
                }
                (Err(e), DepthSource::Embedded) => return Err(DepthNetError::Embedded(e)),
                (Err(e), _) => {
                    log::warn!("{e}; estimating depth with the network instead");
                    embedded_error = Some(e);
                }
                (Ok(None), _) => {}
            }
        }
        let net = self.loaded_net(load_ms)?;
        let (map, mut report) = network_depth(&net, photo, &self.opts)?;
        report.embedded_error = embedded_error;
        Ok((map, report))
    }

    fn embedded(
        &self,
        photo_path: &Path,
        photo: &RgbImage,
    ) -> Result<Option<(DepthMap, StageReport)>, String> {
        let Some(found) = embedded_depth::read(photo_path).map_err(|e| e.to_string())? else {
            return Ok(None);
        };
        embedded_scene_depth(&found, photo, &self.opts)
            .map(Some)
            .map_err(|e| format!("{}: {e}", photo_path.display()))
    }
}

fn percentile(values: &[f32], q: f64) -> f32 {
    let mut sorted = values.to_vec();
    let k = ((sorted.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    let (_, v, _) = sorted.select_nth_unstable_by(k, f32::total_cmp);
    *v
}

#[cfg(test)]
mod tests;
