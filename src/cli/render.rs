//! `reshader render`: all views of a board from a photo, and every product.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use reshader::io::output;
use reshader::pipeline::{self, Product, RenderOptions};

use crate::args::{keyword, parse_pair, FilterArgs, RelocateArgs, SceneArgs};

pub const RENDER_ABOUT: &str = "\
Render all views of a board from a photo.

Depth (--depth): by default the depth the photo carries (Google GDepth XMP or Android
Dynamic Depth), else the depth network (the shipped Tiefenrausch model, or
--depth-model), mapped to scene depth from --near to --near + --depth-budget. Or give a
depth file: --depth depth.npy (add --depth-kind disparity for relative disparity).
run.json says which (inputs.depth.source: file, embedded or network).

Writes into --out:
  views/view_00.png … view_{N-1}.png   view 0 is the leftmost camera
  quilt_qs{cols}x{rows}a{aspect}.png   Looking-Glass quilt, view 0 bottom-left
  panel.png                            the frame woven for the board's panel
  sbs.png                              side-by-side pair (outermost views, or --sbs-pair)
  rgbd.png                             the photo beside its depth (grey, near = white),
                                       focus and depthiness in its text chunks
  preview.gif                          the views swept left to right and back
  preview.html                         one self-contained page showing the view under
                                       the pointer or a finger
  run.json                             inputs with sha256 (and where depth came from),
                                       board, camera per view, timings

Cameras sit on a horizontal line, view 0 leftmost. With --depthiness 1 the outermost
cameras see the zero-parallax plane (--focus, default: the depth halfway between the
scene's near and far parts in disparity) at the edges of the board's view cone; by
default the baseline is reduced so that the outermost views move nothing by more than
3% of the view width. Points on the zero-parallax plane stay put between views.

Examples:
  reshader render photo.jpg --board looking-glass-portrait --out out/
  reshader render photo.jpg --board looking-glass-portrait --out out/ \\
      --depth-precision int8 --near 1.5 --depth-budget 3
  reshader render photo.jpg --depth depth.png --depth-kind disparity \\
      --board looking-glass-portrait --out out/";

#[derive(Args)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub relocate: RelocateArgs,
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long)]
    pub board: String,
    /// Per-unit calibration in Looking-Glass visual.json form; overrides the board's values.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Scales the camera baseline: 1 spans the board's view cone, 0 is flat [default: the
    /// largest value (at most 1) that keeps the outermost views' parallax within 3% of the
    /// view width].
    #[arg(long, allow_negative_numbers = true)]
    pub depthiness: Option<f64>,
    /// Scales the baseline of the cameras each view is reshaded for, as --depthiness scales
    /// the views' [default: the widest, at most 1, that keeps the outermost ones within the
    /// reach of the reshading model's training data, and at least --depthiness].
    #[arg(long, allow_negative_numbers = true)]
    pub shading_depthiness: Option<f64>,
    #[command(flatten)]
    pub filter: FilterArgs,
    /// Write only these products (comma-separated); run.json is always written.
    #[arg(long, value_parser = keyword::<Product>(), value_delimiter = ',')]
    pub only: Vec<Product>,
    /// The two views of sbs.png, as LEFT,RIGHT [default: outermost].
    #[arg(long, value_parser = parse_pair)]
    pub sbs_pair: Option<(usize, usize)>,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `reshader render`.
pub fn render(args: RenderArgs) -> Result<()> {
    // Everything that can be checked without the photo is checked before any work.
    output::check_output_dir(&args.out)?;
    for d in [args.depthiness, args.shading_depthiness]
        .into_iter()
        .flatten()
    {
        reshader::views::check_depthiness(d)?;
    }
    args.scene.reshade.check_model()?;
    let mut board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    args.filter.apply(&mut board)?;
    // The memory the sizes imply, before anything large is allocated. A photo whose
    // header cannot be read is reported by loading it; its board still counts.
    let photo_size = reshader::io::photo::header_size(&args.scene.photo).unwrap_or((1, 1));
    let size = reshader::pipeline::preflight::render_size(
        photo_size,
        &board,
        &args.only,
        &args.scene.reshade.config(),
        args.scene.estimates_depth(),
    );
    reshader::pipeline::preflight::check_memory(
        format!(
            "rendering a {}x{} photo for {} ({} views of {}x{})",
            photo_size.0,
            photo_size.1,
            board.name(),
            board.views(),
            board.view_size().0,
            board.view_size().1
        ),
        &reshader::pipeline::preflight::estimate(&size),
        reshader::pipeline::preflight::RENDER_HINT,
    )?;
    let depth = args.scene.scene_depth()?;
    let reshader = args.scene.reshade.config().build()?;
    let board_file = Path::new(&args.board)
        .is_file()
        .then(|| PathBuf::from(&args.board));
    let views = board.views();
    let opts = RenderOptions {
        photo: args.scene.photo,
        depth,
        fov: args.scene.fov,
        board,
        board_file,
        calibration: args.calibration,
        focus: args.scene.focus,
        depthiness: args.depthiness,
        shading_depthiness: args.shading_depthiness,
        only: args.only,
        sbs_pair: args.sbs_pair,
        out_dir: args.out,
        progress: reshader::pipeline::progress::Progress::start(views as u64, "views", false),
    };
    let record = pipeline::render(&opts, &*reshader, &*args.relocate.config().build())?;
    println!(
        "{}: {} views, wrote {} files to {}",
        opts.board.name(),
        record.views.len(),
        record.outputs.len(),
        opts.out_dir.display()
    );
    Ok(())
}
