//! `reshader eval-relocation`: the relocation methods scored against rendered novel views.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::eval::relocation::{run, EvalConfig, EvalDepth, COARSE_FACTOR};
use reshader::relocate::ldi::{Border, Silhouettes, BAND_SMOOTHING_PX};

use crate::args::{keyword, ReshadeArgs};

pub const EVAL_ABOUT: &str = "\
Score the relocation methods against ground-truth novel views rendered by the dataset
renderer (models/train: one folder per example with input.exr, reshaded.exr, novel.exr,
depth.exr, mask.png, meta.json), with the ground-truth depth or the depth network's: the
input unmoved, the first mesh warp and the layered depth image, each with the input's
colours and with the rendered reshaded colours. Prints mean PSNR / SSIM over valid
pixels, pixels visible in the input and the disoccluded band (the paper's Table 1 for
our relocators); PSNR in a band around the true depth edges, in the region the input
does not see and beyond the frame's border (where halos, streaks and stretched columns
show); and the LDI's build and per-view render times.

Examples:
  reshader eval-relocation data/reshade/val --sheets sheets/ --json eval.json
  reshader eval-relocation data/reshade/val --depth-source network --border inpaint
  reshader eval-relocation data/heldout-640/rooms --depth-source network \
      --depth-model runs/depth/tuned-fp32.onnx";

/// `reshader eval-relocation`'s arguments.
#[derive(Clone, Debug, Args)]
pub struct EvalArgs {
    /// Dataset split folder, e.g. data/reshade/val.
    pub data: PathBuf,
    /// Evaluate at most this many examples (in name order).
    #[arg(long)]
    pub limit: Option<usize>,
    #[arg(long, default_value_t = 5.5)]
    pub exposure: f32,
    #[arg(long, default_value_t = 2.2)]
    pub gamma: f32,
    /// What the LDI shows beyond the photo's borders (as `render --border`).
    #[arg(long, value_parser = keyword::<Border>(), default_value = "extend")]
    pub border: Border,
    /// How the LDI draws the pixels that mix the two sides of a depth step (as `render
    /// --silhouettes`).
    #[arg(long, value_parser = keyword::<Silhouettes>(), default_value = "soft")]
    pub silhouettes: Silhouettes,
    /// Radius in pixels of the box that smooths the LDI's inpainted background (as
    /// `render --band-smoothing`; 0: the synthesised texture).
    #[arg(long, default_value_t = BAND_SMOOTHING_PX, value_name = "PX")]
    pub band_smoothing: usize,
    /// Depth the methods relocate with: the renderer's (`truth`), the shipped depth
    /// network's (`network`: fp32, refined as `render` does) scale-aligned to the
    /// renderer's in disparity, as a real photo's depth would be, or the renderer's with
    /// a network's edges (`coarse`: shrunk to a third, grown back and refined as
    /// `render` refines network depth; right shapes, soft edges).
    #[arg(long, value_parser = keyword::<EvalDepth>(), default_value = "truth")]
    pub depth_source: EvalDepth,
    /// With `--depth-source network`: this depth model (an .onnx with its manifest
    /// beside it, or the manifest) instead of the shipped one, e.g. one fine-tuned by
    /// `reshader-train train-depth`.
    #[arg(long)]
    pub depth_model: Option<PathBuf>,
    /// With `--depth-source coarse`: how many times coarser than the photo the depth is
    /// made before it is grown back and refined (3: a 384-px network serving a
    /// 1,000-px photo; 1.5-2: `render`, which refines at the views' size).
    #[arg(long, default_value_t = COARSE_FACTOR, value_parser = coarse_factor)]
    pub coarse_factor: f64,
    /// Also write the per-example numbers as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write contact sheets here, one PNG per example: top row relocation alone (input |
    /// mesh-warp | ldi | ground-truth novel view), bottom row the same with the
    /// ground-truth reshaded colours (reshaded input | mesh-warp | ldi | disoccluded band
    /// in magenta over the LDI view).
    #[arg(long)]
    pub sheets: Option<PathBuf>,
    /// The reshading model whose colours the LDI also relocates (`--model none`: the
    /// input's, which repeats the relocation-alone row).
    #[command(flatten)]
    pub reshade: ReshadeArgs,
}

/// A factor of at least 1 (1: the true depth refined as network depth is).
fn coarse_factor(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(f) if f.is_finite() && f >= 1.0 => Ok(f),
        _ => Err(format!("'{s}' is not a factor of 1 or more")),
    }
}

/// Runs `reshader eval-relocation` and prints the table.
pub fn eval_relocation(args: &EvalArgs) -> Result<()> {
    if args.depth_model.is_some() && args.depth_source != EvalDepth::Network {
        anyhow::bail!("--depth-model needs --depth-source network");
    }
    let config = EvalConfig {
        data: args.data.clone(),
        limit: args.limit,
        exposure: args.exposure,
        gamma: args.gamma,
        border: args.border,
        silhouettes: args.silhouettes,
        band_smoothing: args.band_smoothing,
        depth_source: args.depth_source,
        depth_model: args.depth_model.clone(),
        coarse_factor: args.coarse_factor,
        json: args.json.clone(),
        sheets: args.sheets.clone(),
        reshade: args.reshade.config(),
    };
    let (_, table) = run(&config)?;
    println!("{table}");
    Ok(())
}
