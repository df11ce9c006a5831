//! `reshader sheet`: what reshading does to a photo on a board's outermost views.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::io::output;
use reshader::pipeline;

use crate::args::{RelocateArgs, SceneArgs};
use crate::view::check_single_view_memory;

pub const SHEET_ABOUT: &str = "\
One picture of what reshading does to a photo on a board. Top row: the photo reshaded
for the board's leftmost view, the photo, reshaded for the rightmost view (all in the
photo's own frame, so only the shading differs); bottom row: the leftmost view, the
difference of the two reshaded images x4, the rightmost view, as the panel shows them.
A highlight that slides between the views shows in the middle as a bright pair of
crescents. The views' cameras, zero-parallax depth and depthiness are render's; the
command prints the outermost offsets and how much of the picture the shading changes.

Examples:
  reshader sheet photo.jpg --board looking-glass-go --out sheet.png
  reshader sheet photo.jpg --board looking-glass-go --model none --out unshaded.png";

#[derive(Args)]
pub struct SheetArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub relocate: RelocateArgs,
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long, default_value = "looking-glass-go")]
    pub board: String,
    /// Scales the camera baseline, as `render --depthiness`.
    #[arg(long, allow_negative_numbers = true)]
    pub depthiness: Option<f64>,
    /// Scales the baseline of the cameras each view is reshaded for, as --depthiness scales
    /// the views' [default: the widest, at most 1, that keeps the outermost ones within the
    /// reach of the reshading model's training data, and at least --depthiness].
    #[arg(long, allow_negative_numbers = true)]
    pub shading_depthiness: Option<f64>,
    /// Output image (.png).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `reshader sheet`.
pub fn sheet(args: SheetArgs) -> Result<()> {
    output::FileFormat::require(&args.out, &[output::FileFormat::Png])?;
    output::check_output_file(&args.out)?;
    args.scene.reshade.check_model()?;
    check_single_view_memory(&args.scene, true)?;
    let board = pipeline::load_board(&args.board, None)?;
    for d in [args.depthiness, args.shading_depthiness]
        .into_iter()
        .flatten()
    {
        reshader::views::check_depthiness(d)?;
    }
    let scene = args.scene.load(Some(board.view_size()))?;
    let reshader = args.scene.reshade.config().build()?;
    let relocator = args.relocate.config().build();
    let sheet = pipeline::sheet::outer_views(
        &scene,
        &board,
        (args.scene.focus, args.depthiness),
        args.shading_depthiness,
        &*reshader,
        &*relocator,
    )?;
    let bytes = output::encode_png(&args.out, &sheet.image)?;
    output::write_atomic(&args.out, &bytes)?;
    println!(
        "{}: {} views {:+.3} and {:+.3}, reshaded for cameras {:+.3} and {:+.3} (depth-map units); the shading changes {:.1}% of the pixels by more than one 8-bit level, mean |difference| {:.4}",
        args.out.display(),
        board.name(),
        sheet.offsets[0],
        sheet.offsets[1],
        sheet.shading_offsets[0],
        sheet.shading_offsets[1],
        100.0 * sheet.changed_share,
        sheet.mean_change
    );
    Ok(())
}
