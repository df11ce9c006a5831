//! Which reshading network a command loads, and its one constructor.

use std::path::{Path, PathBuf};

use crate::engine;
use crate::engine::manifest::Precision;
use crate::reshade::{IdentityReshader, Reshader};

use super::lobes::{heads_in, LobeReshader};
use super::{NetError, NetOptions, NetReshader};

/// The kind of model folder the shipped reshading models are in (`models/reshade`, found
/// at run time by [`crate::engine::locate`]).
pub const SHIPPED_KIND: &str = "reshade";

/// Which reshading network to load and how to run it: what the reshading options of
/// every command that reshades describe.
#[derive(Clone, Debug, PartialEq)]
pub struct ReshadeConfig {
    /// A manifest (the single graph, or either half of an encoder/decoder pair), a folder
    /// of them, or `none`; `None`: `$RESHADER_MODEL`, else the shipped folder.
    pub model: Option<PathBuf>,
    /// `None`: a manifest file's own precision, int8 for a folder.
    pub precision: Option<Precision>,
    /// `tract`, or `ort` (a build with the `ort` feature).
    pub engine: String,
    /// Working resolution as a fraction of the photo's.
    pub scale: f64,
    /// The working resolution's longest side at most this (None: no limit).
    pub max_side: Option<usize>,
    /// Views the network runs for; the others interpolate (`None`: every view).
    pub key_views: Option<usize>,
    /// Views per decoder call.
    pub batch: usize,
    /// Views decoded at once, each on its own thread.
    pub parallel_views: usize,
    /// `None`: every core.
    pub threads: Option<usize>,
    /// `None`: the model's own head (see [`ReshadeConfig::head_for`]).
    pub head: Option<Head>,
    /// Residual head: views changed at under this share of their pixels keep the photo.
    pub gate: f64,
}

impl Default for ReshadeConfig {
    fn default() -> Self {
        Self {
            model: None,
            precision: None,
            engine: "tract".into(),
            scale: 1.0,
            max_side: Some(super::DEFAULT_MAX_SIDE),
            key_views: Some(super::DEFAULT_KEY_VIEWS),
            batch: 1,
            parallel_views: 1,
            threads: None,
            head: None,
            gate: super::DEFAULT_VIEW_GATE,
        }
    }
}

/// The two reshading heads a model can have; its manifest's task says which.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Head {
    /// The paper's residual network (tasks reshade, reshade-encoder, reshade-decoder).
    Residual,
    /// Per-pixel lobes once per photo, a closed form per view (task reshade-lobes).
    Lobes,
}

impl crate::io::keyword::Keyword for Head {
    const ALL: &'static [(Self, &'static str)] =
        &[(Head::Residual, "residual"), (Head::Lobes, "lobes")];
}

impl std::fmt::Display for Head {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(crate::io::keyword::Keyword::keyword(*self))
    }
}

/// The head a model directory holding both kinds is loaded with when --head is not given.
pub const DEFAULT_HEAD: Head = Head::Residual;

/// The precision a model directory is searched for when `--precision` is not given.
pub const DEFAULT_PRECISION: Precision = Precision::Int8;

impl ReshadeConfig {
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
            scale: self.scale,
            max_side: self.max_side,
            key_views: self.key_views,
            batch: self.batch,
            parallel_views: self.parallel_views,
            max_offset: None,
            gate: self.gate,
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
                        "no reshading model in models/reshade (looked in {}; pass --model): views keep the photo's shading",
                        shipped_places()
                    );
                    return Ok(Box::new(IdentityReshader));
                }
            },
        };
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = self.threads.unwrap_or(cores);
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

/// The shipped reshading models' folder, if there is one.
pub fn default_model_dir() -> Option<PathBuf> {
    crate::engine::locate::model_dir(SHIPPED_KIND)
}

fn shipped_places() -> String {
    crate::engine::locate::model_dirs(SHIPPED_KIND)
        .iter()
        .map(|d| d.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}
