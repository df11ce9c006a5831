//! `reshader depth`: a photo's depth, estimated and written to a depth file.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::depth::net::{check_depth_file, write_depth_file, DepthSource};
use reshader::engine::manifest::Precision;

use crate::args::{keyword, parse_depth_precision, DepthStageArgs};

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

/// `reshader depth`'s arguments.
#[derive(Clone, Debug, Args)]
pub struct DepthArgs {
    /// The photo (JPEG or PNG).
    pub photo: PathBuf,
    /// Output depth map: .npy (float32), .pfm, .exr or 16-bit .png (thousandths of a unit).
    #[arg(long)]
    pub out: PathBuf,
    /// Where depth comes from: auto (embedded in the photo if present, else the network),
    /// network, or embedded (an error if the photo has none).
    #[arg(long, value_parser = keyword::<DepthSource>(), default_value = "auto")]
    pub depth: DepthSource,
    /// Precision of the shipped depth model: fp32 (faster in tract, and tuned on renders
    /// for cleaner depth edges) or int8 (smaller; the original, untuned network).
    #[arg(long, default_value = "fp32", value_parser = parse_depth_precision)]
    pub precision: Precision,
    #[command(flatten)]
    pub stage: DepthStageArgs,
}

/// Runs `reshader depth` and prints what it wrote.
pub fn depth(args: &DepthArgs) -> Result<()> {
    check_depth_file(&args.out)?;
    if args.depth != DepthSource::Embedded {
        reshader::pipeline::preflight::check_memory(
            "loading the depth network",
            &reshader::pipeline::preflight::depth_network_estimate(false),
            "",
        )?;
    }
    let estimator = args.stage.config(args.precision).estimator(args.depth)?;
    let (map, report) = write_depth_file(&estimator, &args.photo, &args.out)?;
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
    println!(
        "depth from {} ({what}, {}x{} -> {}x{}) in {:.2} s, depth {lo:.3}..{hi:.3}: wrote {}",
        report.source,
        report.native_size[0],
        report.native_size[1],
        map.width(),
        map.height(),
        report.time_ms / 1e3,
        args.out.display()
    );
    Ok(())
}
