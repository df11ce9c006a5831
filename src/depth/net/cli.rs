//! Command-line options of the depth stage, shared by `reshader depth` and the commands
//! that estimate depth when no depth file is given (flattened into their arguments).

use std::path::PathBuf;

use crate::depth::refine::RefineOptions;
use crate::depth::DepthError;
use crate::engine::manifest::Precision;
use crate::io::output::{self, OutputError};
use crate::io::photo::PhotoError;

use super::{DepthEstimator, DepthNetError, DepthSource, NetChoice, SceneScale, StageOptions};

pub const DEPTH_ABOUT: &str = "\
Estimate scene depth for a photo and write it at the photo's resolution.

Depth comes from the photo itself when it carries some (Google GDepth XMP or Android
Dynamic Depth, as portrait-mode phone photos do), else from the depth network (the
shipped Tiefenrausch model, or --depth-model). Relative network output is mapped so the
scene spans --near to --near + --depth-budget; embedded or metric depth keeps its units.
Depth edges are then snapped to the photo's edges (--no-depth-refine to skip).

The output (.npy float32, .pfm, .exr, or 16-bit .png in thousandths) is what
`render --depth FILE` reads with the default --depth-kind depth.

Examples:
  reshader depth photo.jpg --out depth.npy
  reshader depth photo.jpg --out depth.npy --precision int8 --near 1.5 --depth-budget 3
  reshader depth photo.jpg --out depth.npy --depth-model depth_anything_v2_small.onnx
  reshader depth portrait.jpg --out depth.npy --depth embedded";

#[derive(Debug, thiserror::Error)]
pub enum DepthCommandError {
    #[error(transparent)]
    Photo(#[from] PhotoError),
    #[error(transparent)]
    Net(#[from] DepthNetError),
    #[error(transparent)]
    Depth(#[from] DepthError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{0}")]
    Options(String),
    #[error(transparent)]
    Memory(#[from] crate::pipeline::preflight::OverBudget),
}

/// `reshader depth`.
#[derive(Clone, Debug, clap::Args)]
pub struct DepthCommandArgs {
    /// The photo (JPEG or PNG).
    pub photo: PathBuf,
    /// Output depth map: .npy (float32), .pfm, .exr or 16-bit .png (thousandths of a unit).
    #[arg(long)]
    pub out: PathBuf,
    /// Where depth comes from: auto (embedded in the photo if present, else the network),
    /// network, or embedded (an error if the photo has none).
    #[arg(long, value_enum, default_value_t = DepthSource::Auto)]
    pub depth: DepthSource,
    /// Precision of the shipped depth model: fp32 (faster in tract) or int8 (smaller).
    #[arg(long, default_value = "fp32", value_parser = parse_depth_precision)]
    pub precision: Precision,
    #[command(flatten)]
    pub stage: DepthStageArgs,
}

/// Runs `reshader depth`; returns the summary line to print.
pub fn run_depth(args: &DepthCommandArgs) -> Result<String, DepthCommandError> {
    let all = [
        output::FileFormat::Npy,
        output::FileFormat::Pfm,
        output::FileFormat::Exr,
        output::FileFormat::Png,
    ];
    output::FileFormat::require(&args.out, &all)?;
    output::check_output_file(&args.out)?;
    if args.depth != DepthSource::Embedded {
        crate::pipeline::preflight::check_memory(
            "loading the depth network",
            &crate::pipeline::preflight::depth_network_estimate(false),
            "",
        )?;
    }
    let estimator = args
        .stage
        .estimator(args.depth, args.precision)
        .map_err(DepthCommandError::Options)?;
    let photo = crate::io::photo::load_rgb8(&args.photo)?;
    let mut timings = crate::io::record::Timings::default();
    let (map, report) = estimator.depth(&args.photo, &photo, &mut timings)?;
    let bytes = map.encode(&args.out)?;
    output::write_atomic(&args.out, &bytes)?;
    log::info!(
        "depth stage: {}",
        serde_json::to_string(&report).unwrap_or_default()
    );
    let what = match (&report.model, &report.embedded) {
        (Some(model), _) => model.clone(),
        (None, Some(e)) => format!("{} {}", e.container, e.format),
        (None, None) => String::new(),
    };
    let [lo, hi] = report.depth_range;
    Ok(format!(
        "depth from {} ({what}, {}x{} -> {}x{}) in {:.2} s, depth {lo:.3}..{hi:.3}: wrote {}",
        report.source,
        report.native_size[0],
        report.native_size[1],
        map.width(),
        map.height(),
        report.time_ms / 1e3,
        args.out.display()
    ))
}

#[derive(Clone, Debug, clap::Args)]
pub struct DepthStageArgs {
    /// Depth model: an .onnx file with its .json manifest beside it (same stem), or the
    /// manifest. Default: the shipped Tiefenrausch model (models/depth, or the directory
    /// $RESHADER_DEPTH_MODELS).
    #[arg(long)]
    pub depth_model: Option<PathBuf>,
    /// Inference engine for the depth network: tract, or ort (needs --features ort).
    #[arg(long, default_value = "tract")]
    pub depth_engine: String,
    /// Threads for the depth network (default: every core).
    #[arg(long)]
    pub depth_threads: Option<usize>,
    /// Scene depth given to the near end of relative depth (its 98th disparity percentile).
    #[arg(long, default_value_t = crate::depth::NEAR, allow_negative_numbers = true)]
    pub near: f32,
    /// The far end of relative depth (2nd disparity percentile) lands at near + this.
    #[arg(long, default_value_t = crate::depth::FAR - crate::depth::NEAR, allow_negative_numbers = true)]
    pub depth_budget: f32,
    /// Keep the upsampled depth as it is (no edge refinement with the photo).
    #[arg(long)]
    pub no_depth_refine: bool,
}

impl DepthStageArgs {
    /// The network to use, with the shipped model's precision.
    pub fn net(&self, precision: Precision) -> NetChoice {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        NetChoice {
            model: self.depth_model.clone(),
            precision,
            engine: self.depth_engine.clone(),
            threads: self.depth_threads.unwrap_or(cores).max(1),
        }
    }

    /// The estimator these options describe; the network is loaded on first use.
    pub fn estimator(
        &self,
        source: DepthSource,
        precision: Precision,
    ) -> Result<DepthEstimator, String> {
        Ok(DepthEstimator::new(
            source,
            self.net(precision),
            self.options()?,
        ))
    }

    pub fn options(&self) -> Result<StageOptions, String> {
        let scale = SceneScale {
            near: self.near,
            budget: self.depth_budget,
        };
        scale.check()?;
        Ok(StageOptions {
            scale,
            refine: (!self.no_depth_refine).then(RefineOptions::default),
        })
    }
}

/// The depth-estimation options of the commands that render (`render`, `view`,
/// `reshade`, `convert`, `watch`), used when no depth file is given.
#[derive(Clone, Debug, clap::Args)]
#[command(next_help_heading = "Depth estimation (when no depth file is given)")]
pub struct EstimateArgs {
    /// Precision of the shipped depth model: fp32 (faster in tract) or int8 (smaller).
    #[arg(long, default_value = "fp32", value_parser = parse_depth_precision)]
    pub depth_precision: Precision,
    #[command(flatten)]
    pub stage: DepthStageArgs,
}

impl EstimateArgs {
    pub fn estimator(&self, source: DepthSource) -> Result<DepthEstimator, String> {
        self.stage.estimator(source, self.depth_precision)
    }
}

/// `--depth` of the rendering commands: a file, or where to get depth without one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DepthInput {
    File(PathBuf),
    Estimate(DepthSource),
}

impl Default for DepthInput {
    fn default() -> Self {
        DepthInput::Estimate(DepthSource::Auto)
    }
}

impl std::str::FromStr for DepthInput {
    type Err = String;

    /// `auto`, `network` and `embedded` are keywords (a file of that name: `./auto`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s {
            "" => return Err("expected a depth file or auto, network, embedded".into()),
            "auto" => DepthInput::Estimate(DepthSource::Auto),
            "network" => DepthInput::Estimate(DepthSource::Network),
            "embedded" => DepthInput::Estimate(DepthSource::Embedded),
            path => DepthInput::File(PathBuf::from(path)),
        })
    }
}

/// Parses `--precision` of the depth models (only int8 and fp32 are shipped).
pub fn parse_depth_precision(s: &str) -> Result<Precision, String> {
    match s.parse::<Precision>()? {
        Precision::Fp16 => Err("the depth models ship as int8 and fp32".into()),
        p => Ok(p),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_keywords_and_files() {
        assert_eq!("auto".parse(), Ok(DepthInput::Estimate(DepthSource::Auto)));
        assert_eq!(
            "embedded".parse(),
            Ok(DepthInput::Estimate(DepthSource::Embedded))
        );
        assert_eq!("./auto".parse(), Ok(DepthInput::File("./auto".into())));
        assert!(parse_depth_precision("fp16").is_err());
        assert_eq!(parse_depth_precision("int8"), Ok(Precision::Int8));
    }
}
