//! The render pipeline as a gallery [`Converter`]: `convert` and `watch` turn each photo
//! into a board's outputs with it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use interleave::Board;

use super::photos::find_depth;
use super::{ConvertError, ConvertReport, Converter, FnConverter, OutLayout};
use crate::depth::holes::HolePolicy;
use crate::depth::net::{DepthConfig, DepthEstimator, DepthNetError, DepthSource};
use crate::pipeline::progress::Progress;
use crate::pipeline::{self, Product, RenderOptions, SceneDepth};
use crate::relocate::RelocateConfig;
use crate::reshade::net::choice::ReshadeConfig;
use crate::reshade::net::NetError;
use crate::reshade::Reshader;

#[derive(Debug, thiserror::Error)]
pub enum GalleryError {
    #[error(transparent)]
    Board(#[from] interleave::BoardError),
    #[error(transparent)]
    Watch(#[from] super::watch::WatchError),
    #[error(transparent)]
    DepthNet(#[from] DepthNetError),
    #[error(transparent)]
    ReshadeNet(#[from] NetError),
    #[error(transparent)]
    Scale(#[from] crate::depth::ScaleError),
    #[error(transparent)]
    Output(#[from] crate::io::output::OutputError),
    #[error(transparent)]
    ModelPath(#[from] crate::pipeline::preflight::ModelPathError),
    #[error(transparent)]
    Memory(#[from] crate::pipeline::preflight::OverBudget),
}

/// What `convert` and `watch` render each photo with.
#[derive(Clone, Debug, Default)]
pub struct GalleryConfig {
    /// A built-in board's name or a board file.
    pub board: String,
    /// A unit's calibration (Looking Glass visual.json).
    pub calibration: Option<PathBuf>,
    /// Each photo's outputs in OUT/NAME/ (`None`: NAME.reshader/ beside the photo).
    pub out: Option<PathBuf>,
    /// Products to write (empty: all).
    pub only: Vec<Product>,
    pub depthiness: Option<f64>,
    /// Holes in depth sidecars.
    pub depth_holes: HolePolicy,
    pub relocate: RelocateConfig,
    pub depth: DepthConfig,
    pub reshade: ReshadeConfig,
}

impl GalleryConfig {
    /// Where each photo's outputs go.
    pub fn layout(&self) -> OutLayout {
        match &self.out {
            Some(dir) => OutLayout::Under(dir.clone()),
            None => OutLayout::BesidePhoto,
        }
    }
}

/// The render pipeline as a converter: the board, the depth network and the reshading
/// network are loaded here, once, and shared by every photo (a bad --depth-model or
/// --model fails before any photo).
pub fn pipeline_converter(args: &GalleryConfig) -> Result<impl Converter, GalleryError> {
    if let Some(out) = &args.out {
        crate::io::output::check_output_dir(out)?;
    }
    if let Some(model) =
        crate::pipeline::preflight::chosen_reshade_model(args.reshade.model.as_deref())
    {
        crate::pipeline::preflight::check_model_path("--model", &model)?;
    }
    let board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    let estimator = args.depth.estimator(DepthSource::Auto)?;
    // The depth network is loaded here, once, before any photo: first its memory.
    crate::pipeline::preflight::check_memory(
        "loading the depth network",
        &crate::pipeline::preflight::depth_network_estimate(
            crate::pipeline::preflight::reshading_on(args.reshade.model.as_deref()),
        ),
        "",
    )?;
    estimator.net()?;
    let reshader = args.reshade.build()?;
    let fingerprint = fingerprint(args, &board, &estimator, &*reshader);
    let estimator = Arc::new(estimator);
    let board_file = Path::new(&args.board)
        .is_file()
        .then(|| PathBuf::from(&args.board));
    let only = args.only.clone();
    let calibration = args.calibration.clone();
    let depthiness = args.depthiness;
    let holes = args.depth_holes;
    let relocator = args.relocate.build();
    let reshade_args = args.reshade.clone();
    let converter = FnConverter::new(
        fingerprint,
        move |photo: &Path, out_dir: &Path| -> Result<ConvertReport, ConvertError> {
            crate::io::output::check_output_dir(out_dir)?;
            let sidecar = find_depth(photo);
            if let Some(size) = crate::io::photo::header_size(photo) {
                let need = crate::pipeline::preflight::render_size(
                    size,
                    &board,
                    &only,
                    &reshade_args,
                    sidecar.is_none(),
                );
                crate::pipeline::preflight::check_memory(
                    format!(
                        "photo {}: rendering it ({}x{})",
                        photo.display(),
                        size.0,
                        size.1
                    ),
                    &crate::pipeline::preflight::estimate(&need),
                    crate::pipeline::preflight::RENDER_HINT,
                )?;
            }
            let depth = match sidecar {
                Some((path, kind)) => SceneDepth::File { path, kind, holes },
                None => SceneDepth::Estimate(Arc::clone(&estimator)),
            };
            let opts = RenderOptions {
                photo: photo.into(),
                depth,
                fov: None,
                board: board.clone(),
                board_file: board_file.clone(),
                calibration: calibration.clone(),
                focus: None,
                depthiness,
                shading_depthiness: None,
                only: only.clone(),
                sbs_pair: None,
                out_dir: out_dir.into(),
                progress: Progress::hidden(),
            };
            let record = pipeline::render(&opts, &*reshader, &*relocator)?;
            Ok(ConvertReport {
                outputs: record.outputs.iter().map(|o| out_dir.join(o)).collect(),
                timings_ms: record
                    .timings_ms
                    .stages()
                    .iter()
                    .cloned()
                    .collect::<BTreeMap<_, _>>(),
            })
        },
    );
    // The depth sidecar is an input: editing it converts the photo again.
    Ok(converter.with_inputs(|photo| {
        find_depth(photo)
            .map(|(path, _)| path)
            .into_iter()
            .collect()
    }))
}

/// Everything that changes a conversion's outputs, so that changing it reconverts.
fn fingerprint(
    args: &GalleryConfig,
    board: &Board,
    estimator: &DepthEstimator,
    reshader: &dyn Reshader,
) -> String {
    let calibration = args
        .calibration
        .as_deref()
        .map(|p| crate::io::record::sha256_file(p).unwrap_or_else(|e| format!("unreadable: {e}")));
    format!(
        "reshader {}; board {} from {}; calibration {:?}; only {:?}; depthiness {:?}; \
         depth holes {}; {}; reshade {}; relocate {}",
        env!("CARGO_PKG_VERSION"),
        board.name(),
        board.origin(),
        calibration,
        args.only,
        args.depthiness,
        crate::io::keyword::Keyword::keyword(args.depth_holes),
        estimator.describe(),
        reshader.description(),
        args.relocate.build().description()
    )
}
