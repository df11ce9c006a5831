//! Model manifests (`models/<dir>/<name>.json` beside `<name>.onnx`): what a model file
//! claims to be, checked against what the runtime is about to feed it before any tensor
//! is allocated. Schema: `reshader-manifest/1` (models/MANIFEST.md).

mod reshade;

pub use reshade::*;

use std::fmt;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use sha2::{Digest, Sha256};

pub const FORMAT: &str = "reshader-manifest/1";

/// The disparity the runtime computes from depth, verbatim as the manifest writes it.
pub const DISPARITY_FORMULA: &str = "clamp(0.25/depth, 0, 1)";
pub const DISPARITY_FREQUENCIES: u32 = 5;
pub const CAMERA_CONVENTION: &str = "opencv";

#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("manifest {path} is not valid: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("manifest {path}: field `{field}` {problem}")]
    Field {
        path: PathBuf,
        field: String,
        problem: String,
    },
    #[error("model {path} does not match its manifest's sha256 (manifest {expected}, file {actual}): the file was changed or truncated")]
    Checksum {
        path: PathBuf,
        expected: String,
        actual: String,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Task {
    Depth,
    Reshade,
    ReshadeEncoder,
    ReshadeDecoder,
    /// The lobe head: image, disparity and rays in, per-pixel lobes out, run once per
    /// photo; the view enters through a closed form (`reshade::net::lobes`).
    ReshadeLobes,
    Inpaint,
}

impl fmt::Display for Task {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Task::Depth => "depth",
            Task::Reshade => "reshade",
            Task::ReshadeEncoder => "reshade-encoder",
            Task::ReshadeDecoder => "reshade-decoder",
            Task::ReshadeLobes => "reshade-lobes",
            Task::Inpaint => "inpaint",
        })
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    Fp32,
    Fp16,
    Int8,
}

impl fmt::Display for Precision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Precision::Fp32 => "fp32",
            Precision::Fp16 => "fp16",
            Precision::Int8 => "int8",
        })
    }
}

impl std::str::FromStr for Precision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fp32" => Ok(Precision::Fp32),
            "fp16" => Ok(Precision::Fp16),
            "int8" => Ok(Precision::Int8),
            _ => Err(format!("unknown precision {s:?}: use int8, fp16 or fp32")),
        }
    }
}

/// One axis of a tensor shape: a fixed size or a symbol such as "H" or "W/32".
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum Dim {
    Fixed(u64),
    Symbol(String),
}

/// As the manifest writes it: 3, or "H".
impl std::fmt::Display for Dim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Fixed(n) => write!(f, "{n}"),
            Self::Symbol(s) => write!(f, "{s:?}"),
        }
    }
}

/// A shape as the manifest writes it: [1, 3, "H", "W"].
pub fn shape_text(shape: &[Dim]) -> String {
    let dims: Vec<String> = shape.iter().map(Dim::to_string).collect();
    format!("[{}]", dims.join(", "))
}

#[derive(Clone, Debug, Deserialize)]
pub struct TensorSpec {
    pub name: String,
    pub dtype: String,
    pub layout: String,
    pub shape: Vec<Dim>,
    pub range: Option<[f64; 2]>,
    #[serde(default)]
    pub description: String,
}

#[derive(Clone, Debug, Deserialize)]
pub struct ImageSpec {
    pub color: String,
    pub range: [f64; 2],
    pub channel_order: String,
    pub mean: Option<Vec<f64>>,
    pub std: Option<Vec<f64>>,
}

#[derive(Clone, Debug, Deserialize)]
pub struct DisparityEncoding {
    pub formula: String,
    pub frequencies: u32,
    pub pi: bool,
    pub in_graph: bool,
}

#[derive(Clone, Debug, Deserialize)]
pub struct CameraSpec {
    pub convention: String,
    pub meaning: String,
    pub training_offset_range: [f64; 2],
}

#[derive(Clone, Debug, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub name: String,
    pub version: String,
    pub task: Task,
    pub precision: Precision,
    pub file: String,
    pub sha256: String,
    pub inputs: Vec<TensorSpec>,
    pub outputs: Vec<TensorSpec>,
    pub size_multiple: u32,
    pub image: Option<ImageSpec>,
    pub disparity_encoding: Option<DisparityEncoding>,
    pub camera: Option<CameraSpec>,
    pub depth: Option<serde_json::Value>,
    pub architecture: Option<serde_json::Value>,
    pub training: Option<serde_json::Value>,
    #[serde(default)]
    pub validation: serde_json::Value,
    pub licence: String,
    pub source: String,
    /// Lobe head only (task `reshade-lobes`): "lobes".
    pub head: Option<String>,
    /// Lobe head only: lobes per pixel (K); the output has 7K channels.
    pub lobes: Option<u64>,
    /// Lobe head only: the 7 channel names of one lobe, in order ([`LOBE_LAYOUT`]).
    pub lobe_layout: Option<Vec<String>>,
    /// Lobe head only: the 7K output channel names.
    pub channels: Option<Vec<String>>,
    /// Lobe head only: the soft threshold applied to the summed change (display units).
    pub deadzone: Option<f64>,
    /// Lobe head only: the encoding the change is added in ("display").
    pub domain: Option<String>,
    /// Lobe head only: the depth at disparity 1 (0.25: disparity = 0.25 / depth).
    pub disparity_depth: Option<f64>,
}

/// A manifest together with where it was read from and the model bytes it vouches for.
#[derive(Clone, Debug)]
pub struct VerifiedModel {
    pub manifest: Manifest,
    pub manifest_path: PathBuf,
    pub model_path: PathBuf,
    pub bytes: Vec<u8>,
}

impl Manifest {
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = std::fs::read_to_string(path).map_err(|source| ManifestError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_json_str(&text, path)
    }

    /// Parses manifest text; `path` names it in errors.
    pub fn from_json_str(text: &str, path: &Path) -> Result<Self, ManifestError> {
        let manifest: Manifest =
            serde_json::from_str(text).map_err(|source| ManifestError::Json {
                path: path.to_owned(),
                source,
            })?;
        if manifest.format != FORMAT {
            return Err(field_error(
                path,
                "format",
                format!("is {:?}; this runtime reads {FORMAT:?}", manifest.format),
            ));
        }
        Ok(manifest)
    }

    pub fn input(&self, name: &str) -> Option<&TensorSpec> {
        self.inputs.iter().find(|t| t.name == name)
    }

    pub fn output(&self, name: &str) -> Option<&TensorSpec> {
        self.outputs.iter().find(|t| t.name == name)
    }
}

/// Loads the manifest at `path`, reads the model file it names and checks its sha256.
pub fn load_verified(path: &Path) -> Result<VerifiedModel, ManifestError> {
    let manifest = Manifest::load(path)?;
    let model_path = path.parent().unwrap_or(Path::new(".")).join(&manifest.file);
    let bytes = std::fs::read(&model_path).map_err(|source| ManifestError::Io {
        path: model_path.clone(),
        source,
    })?;
    let actual = hex(&Sha256::digest(&bytes));
    if !actual.eq_ignore_ascii_case(manifest.sha256.trim()) {
        return Err(ManifestError::Checksum {
            path: model_path,
            expected: manifest.sha256.clone(),
            actual,
        });
    }
    Ok(VerifiedModel {
        manifest,
        manifest_path: path.to_owned(),
        model_path,
        bytes,
    })
}

pub(crate) fn field_error(path: &Path, field: &str, problem: impl Into<String>) -> ManifestError {
    ManifestError::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        problem: problem.into(),
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
