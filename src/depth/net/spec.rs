//! The depth section of a depth model's manifest: how to feed the model (input size
//! policy, resizing, value range, channel order, normalisation) and how to read its
//! output, each field checked and named in the error when it is wrong.

use std::path::Path;

use image::imageops::FilterType;
use image::RgbImage;
use serde::Deserialize;

use crate::depth::RawMap;
use crate::engine::manifest::{self, Manifest, ManifestError, Task};
use crate::engine::Tensor;

use super::resize::area_resize;
use super::{DepthNetError, NetworkDepth, MAX_INPUT_SIDE};

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
    pub(super) fn read_output(
        &self,
        path: &Path,
        out: &Tensor,
    ) -> Result<NetworkDepth, DepthNetError> {
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
