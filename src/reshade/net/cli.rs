//! Command-line options that choose and tune the reshading network, shared by every
//! subcommand that reshades (flattened into their clap arguments).

use std::path::{Path, PathBuf};

use crate::engine;
use crate::engine::manifest::Precision;
use crate::reshade::{IdentityReshader, Reshader};

use super::lobes::{heads_in, LobeReshader};
use super::{NetError, NetOptions, NetReshader};

/// Where the shipped reshading models live, relative to the working directory or the
/// source tree the binary was built from.
pub const DEFAULT_MODEL_DIR: &str = "models/reshade";

#[derive(Clone, Debug, clap::Args)]
pub struct ReshadeArgs {
    /// Reshading model: a manifest (.json; the single graph, or either half of an
    /// encoder/decoder pair) or a directory of them, or `none` to keep the photo's
    /// shading. Default: models/reshade, or $RESHADER_MODEL.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Model precision to load: int8 (the default for a model directory: a quarter of
    /// fp32's weight bytes, at about fp32's speed in tract, which turns the int8
    /// weights into f32 once at load), fp32 or fp16. A --model manifest file is loaded at
    /// its own precision unless this is given. The model must have been exported at that
    /// precision; fp16 weights are computed in f32 on CPUs without fp16 arithmetic.
    #[arg(long, value_parser = parse_precision)]
    pub precision: Option<Precision>,
    /// Inference engine: tract (built in), or ort (onnxruntime from $ORT_DYLIB_PATH; needs
    /// a build with --features ort).
    #[arg(long, default_value = "tract")]
    pub engine: String,
    /// Working resolution of the network as a fraction of the photo's; the predicted
    /// residual is upsampled to full resolution.
    #[arg(long, default_value_t = 1.0)]
    pub reshade_scale: f64,
    /// Run the network for this many views and interpolate the residual for the others
    /// (default: every view).
    #[arg(long)]
    pub key_views: Option<usize>,
    /// Views per decoder call.
    #[arg(long, default_value_t = 1)]
    pub reshade_batch: usize,
    /// Views decoded at the same time, each on its own thread (the engine then uses
    /// --reshade-threads / this many threads per view).
    #[arg(long, default_value_t = 1)]
    pub parallel_views: usize,
    /// Threads for reshading (default: every core).
    #[arg(long)]
    pub reshade_threads: Option<usize>,
    /// Reshading head: residual (the paper's network, run per view) or lobes (a network
    /// run once per photo and a closed form per view). Default: a --model manifest's own
    /// head; for a directory, residual when it holds residual-head models, else lobes.
    #[arg(long, value_enum)]
    pub head: Option<Head>,
}

/// The two reshading heads a model can have; its manifest's task says which.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Head {
    /// The paper's residual network (tasks reshade, reshade-encoder, reshade-decoder).
    Residual,
    /// Per-pixel lobes once per photo, a closed form per view (task reshade-lobes).
    Lobes,
}

impl std::fmt::Display for Head {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Head::Residual => "residual",
            Head::Lobes => "lobes",
        })
    }
}

/// The head a model directory holding both kinds is loaded with when --head is not given.
pub const DEFAULT_HEAD: Head = Head::Residual;

fn parse_precision(s: &str) -> Result<Precision, String> {
    s.parse()
}

/// The precision a model directory is searched for when `--precision` is not given.
pub const DEFAULT_PRECISION: Precision = Precision::Int8;

impl ReshadeArgs {
    /// `--precision`, else the precision of the manifest file `model` names, else int8.
    pub fn precision_for(&self, model: Option<&Path>) -> Precision {
        self.precision.unwrap_or_else(|| {
            model
                .filter(|p| p.is_file())
                .and_then(|p| crate::engine::manifest::Manifest::load(p).ok())
                .map_or(DEFAULT_PRECISION, |m| m.precision)
        })
    }

    /// The head `--head` asks for, else the one the model at `path` has: a manifest's own
    /// (its task), for a directory [`DEFAULT_HEAD`] unless it holds only lobe-head models.
    /// A manifest of the other head than `--head` is refused, naming it.
    pub fn head_for(&self, path: &Path) -> Result<Head, NetError> {
        if path.is_dir() {
            return Ok(self.head.unwrap_or_else(|| match heads_in(path) {
                Ok((true, false)) => Head::Lobes,
                _ => DEFAULT_HEAD,
            }));
        }
        let own = match crate::engine::manifest::Manifest::load(path) {
            Ok(m) if m.task == crate::engine::manifest::Task::ReshadeLobes => Head::Lobes,
            // Unreadable manifests are reported by the loader, with the file's name.
            _ => Head::Residual,
        };
        match self.head {
            Some(asked) if asked != own => Err(NetError::Model {
                path: path.to_owned(),
                problem: format!(
                    "is a {own}-head model but --head {asked} was given: pass a {asked}-head manifest (or its directory), or drop --head"
                ),
            }),
            _ => Ok(own),
        }
    }

    pub fn options(&self) -> NetOptions {
        NetOptions {
            scale: self.reshade_scale,
            key_views: self.key_views,
            batch: self.reshade_batch,
            parallel_views: self.parallel_views,
            max_offset: None,
        }
    }

    /// The reshader these options ask for. Without `--model`, a missing default model
    /// directory falls back to the identity (with a warning); an explicit one must load.
    pub fn build(&self) -> Result<Box<dyn Reshader + Send + Sync>, NetError> {
        let chosen = self
            .model
            .clone()
            .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from));
        let path = match chosen {
            Some(path) if path.as_os_str() == "none" => {
                log::info!("reshading off (--model none): views keep the photo's shading");
                return Ok(Box::new(IdentityReshader));
            }
            Some(path) => path,
            None => match default_model_dir() {
                Some(dir) => dir,
                None => {
                    log::warn!(
                        "no reshading model at {DEFAULT_MODEL_DIR} (pass --model): views keep the photo's shading"
                    );
                    return Ok(Box::new(IdentityReshader));
                }
            },
        };
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = self.reshade_threads.unwrap_or(cores);
        let precision = self.precision_for(Some(&path));
        let net: Box<dyn Reshader + Send + Sync> = match self.head_for(&path)? {
            Head::Residual => {
                let per_view = (threads / self.parallel_views.max(1)).max(1);
                let engine = engine::by_name(&self.engine, per_view)?;
                Box::new(NetReshader::load(&path, precision, engine, self.options())?)
            }
            // One network run per photo on every thread, then the closed form on as many.
            Head::Lobes => {
                let engine = engine::by_name(&self.engine, threads)?;
                Box::new(LobeReshader::load(
                    &path,
                    precision,
                    engine,
                    self.options(),
                )?)
            }
        };
        log::info!("reshading with {}", net.description());
        Ok(net)
    }
}

fn default_model_dir() -> Option<PathBuf> {
    [
        PathBuf::from(DEFAULT_MODEL_DIR),
        Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_MODEL_DIR),
    ]
    .into_iter()
    .find(|p| p.is_dir())
}
