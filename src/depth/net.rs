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

mod file;
mod resize;
mod spec;
mod stage;

pub use file::{check_depth_file, write_depth_file, DepthFileError};
pub use resize::area_resize;
pub use spec::*;
pub use stage::*;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use image::RgbImage;

use crate::depth::embedded as embedded_depth;
use crate::depth::{DepthMap, RawMap};
use crate::engine::manifest::{self, Manifest, ManifestError, Precision, VerifiedModel};
use crate::engine::{Engine, EngineError, ModelSource, Plan};
use crate::io::record::Timings;

/// Where the shipped depth models live, relative to the working directory or the source
/// tree the binary was built from.
pub const DEFAULT_MODEL_DIR: &str = "models/depth";
/// The shipped model at `precision`, as the stem of its manifest in [`DEFAULT_MODEL_DIR`].
/// fp32 is Tiefenrausch fine-tuned on renders; int8 stays the original network, because
/// most of the tuning's weight changes are finer than its 8-bit steps and round away
/// (models/depth/README.md).
pub fn shipped_model(precision: Precision) -> String {
    match precision {
        Precision::Fp32 => "tiefenrausch-tuned-fp32".into(),
        other => format!("tiefenrausch-{other}"),
    }
}

/// The manifest of the shipped model at `precision`: in `$RESHADER_DEPTH_MODELS`, else in
/// `models/depth` where [`crate::engine::locate::model_dirs`] looks.
pub fn shipped_manifest(precision: Precision) -> Result<PathBuf, DepthNetError> {
    let file = format!("{}.json", shipped_model(precision));
    let mut dirs = crate::engine::locate::model_dirs("depth");
    if let Some(dir) = std::env::var_os("RESHADER_DEPTH_MODELS") {
        dirs.insert(0, PathBuf::from(dir));
    }
    let candidates: Vec<PathBuf> = dirs.iter().map(|d| d.join(&file)).collect();
    match candidates.iter().find(|p| p.is_file()) {
        Some(p) => Ok(p.clone()),
        None => Err(DepthNetError::NotFound {
            tried: candidates
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        }),
    }
}
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
    #[error(transparent)]
    Embedded(#[from] crate::depth::embedded::EmbeddedError),
    #[error(
        "no depth model found: looked for {tried}; pass --depth-model FILE (an .onnx with its \
         .json manifest beside it, or the manifest) or --depth FILE"
    )]
    NotFound { tried: String },
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

    /// The shipped model at `precision`, found in `$RESHADER_DEPTH_MODELS`, else in
    /// `models/depth` where [`crate::engine::locate::model_dirs`] looks.
    pub fn shipped(precision: Precision, engine: Arc<dyn Engine>) -> Result<Self, DepthNetError> {
        Self::load(&shipped_manifest(precision)?, engine)
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
            "has no manifest {} beside it: write one (schema: models/MANIFEST.md) saying how to \
             feed the model and what its output means",
            manifest.display()
        ),
    })
}

/// Where the depth of a photo comes from when no depth file is given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DepthSource {
    /// Depth embedded in the photo if it has any, else the network.
    Auto,
    Network,
    Embedded,
}

impl crate::io::keyword::Keyword for DepthSource {
    const ALL: &'static [(Self, &'static str)] = &[
        (Self::Auto, "auto"),
        (Self::Network, "network"),
        (Self::Embedded, "embedded"),
    ];
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
            None => shipped_model(self.choice.precision),
        };
        format!(
            "depth {:?} model {model} near {} budget {} refine {:?}",
            self.source, self.opts.scale.near, self.opts.scale.budget, self.opts.refine
        )
    }

    /// Scene depth for the photo at `photo_path` (decoded upright as `photo`), at `size`
    /// (the photo's, or the smaller size, same aspect, of the views it is for). In `Auto`,
    /// unreadable embedded depth is logged and recorded in the report, and the network is
    /// used instead; asked for explicitly, it is an error.
    ///
    /// Loading the network (first use only) is timed in `t` as `depth_model`; the
    /// report's `time_ms` is the rest of the stage, and `t` gets it as `depth`.
    pub fn depth(
        &self,
        photo_path: &Path,
        photo: &RgbImage,
        size: [usize; 2],
        t: &mut Timings,
    ) -> Result<(DepthMap, StageReport), DepthNetError> {
        let started = std::time::Instant::now();
        let mut load_ms = 0.0;
        let (map, mut report) = self.find(photo_path, photo, size, &mut load_ms)?;
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
        size: [usize; 2],
        load_ms: &mut f64,
    ) -> Result<(DepthMap, StageReport), DepthNetError> {
        let mut embedded_error = None;
        if self.source != DepthSource::Network {
            match (self.embedded(photo_path, photo, size), self.source) {
                (Ok(Some(result)), _) => {
                    log::info!(
                        "{}: using the depth embedded in the photo",
                        photo_path.display()
                    );
                    return Ok(result);
                }
                (Ok(None), DepthSource::Embedded) => {
                    return Err(embedded_depth::EmbeddedError::Missing {
                        path: photo_path.into(),
                    }
                    .into())
                }
                (Err(e), DepthSource::Embedded) => return Err(e.into()),
                (Err(e), _) => {
                    log::warn!("{e}; estimating depth with the network instead");
                    embedded_error = Some(e.to_string());
                }
                (Ok(None), _) => {}
            }
        }
        let net = self.loaded_net(load_ms)?;
        let (map, mut report) = network_depth(&net, photo, size, &self.opts)?;
        report.embedded_error = embedded_error;
        Ok((map, report))
    }

    fn embedded(
        &self,
        photo_path: &Path,
        photo: &RgbImage,
        size: [usize; 2],
    ) -> Result<Option<(DepthMap, StageReport)>, embedded_depth::EmbeddedError> {
        let Some(found) = embedded_depth::read(photo_path)? else {
            return Ok(None);
        };
        embedded_scene_depth(&found, photo, size, &self.opts)
            .map(Some)
            .map_err(|problem| embedded_depth::EmbeddedError::Unfit {
                path: photo_path.into(),
                problem,
            })
    }
}

#[cfg(test)]
mod tests;
