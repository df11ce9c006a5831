use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Result;
use clap::{Args, Parser, Subcommand, ValueEnum};

use reshader::depth::holes::HolePolicy;
use reshader::depth::net::cli::{DepthInput, EstimateArgs};
use reshader::depth::DepthKind;
use reshader::interleave::{Blend, Board};
use reshader::io::output;
use reshader::pipeline::{self, Product, RenderOptions, Scene, SceneDepth, ViewRequest};
use reshader::relocate::RelocateArgs;

const ABOUT: &str = "Turn one photo into the views, quilt and woven frame of a lenticular \
light-field panel.";

const LONG_ABOUT: &str = "\
Turn one photo into the views, quilt and woven frame of a lenticular light-field panel
(Looking Glass and other slanted-lenticular displays).

Depth comes from the photo itself when it carries some (portrait-mode phone photos),
else from the shipped depth network; --depth FILE uses a depth map of your own.

The main job is `render`; every stage also runs alone for scripting and debugging.

Examples:
  # everything for a Looking Glass Portrait: views/, quilt, panel.png, sbs.png, rgbd.png,
  # preview.gif, preview.html, run.json
  reshader render examples/pumpkin/pumpkin.jpg --board looking-glass-portrait --out out/

  # the same with a depth map you have (here the example's relative disparity)
  reshader render examples/pumpkin/pumpkin.jpg --depth examples/pumpkin/pumpkin_disparity.png \\
      --depth-kind disparity --board looking-glass-portrait --out out/

  # only the woven frame and the quilt, with a unit's own calibration
  reshader render photo.jpg --board looking-glass-go --calibration visual.json \\
      --only panel,quilt --out out/

  # one novel view, camera 0.1 units to the right (OpenCV axes: x right, y down, z forward)
  reshader view photo.jpg --camera 0.1,0,0 --out view.png

  # the depth stage alone, and gallery batches
  reshader depth photo.jpg --out depth.npy
  reshader convert ~/DCIM/*.jpg --board looking-glass-go

  # weave views you rendered elsewhere
  reshader weave out/views --board looking-glass-portrait --out panel.png
  reshader weave out/quilt_qs8x6a0.75.png --board looking-glass-portrait --out panel.png

  reshader boards        # the built-in boards

Errors name the file and the problem and exit non-zero; nothing is written then.";

#[derive(Parser)]
#[command(name = "reshader", version, about = ABOUT, long_about = LONG_ABOUT)]
struct Cli {
    /// More log output (-v: progress, -vv: debug).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Memory ceiling for the run (e.g. 2G, 512M): inputs whose decoded size would take
    /// more than a quarter of it are refused, and the kernel holds the heap to it.
    #[arg(long, global = true, value_name = "SIZE", default_value = "4G",
          value_parser = reshader::io::limits::parse_size)]
    max_memory: u64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render all views of a board and write views/, the quilt, panel.png, sbs.png, rgbd.png, the previews and run.json.
    #[command(long_about = RENDER_ABOUT)]
    Render(RenderArgs),
    /// Estimate depth for a photo: the depth it carries, or the depth network.
    #[command(long_about = reshader::depth::net::cli::DEPTH_ABOUT)]
    Depth(reshader::depth::net::cli::DepthCommandArgs),
    /// Reshade the photo for a novel camera, in the input camera's frame.
    #[command(long_about = RESHADE_ABOUT)]
    Reshade(SingleViewArgs),
    /// Render the novel view from one camera position.
    #[command(long_about = VIEW_ABOUT)]
    View(ViewArgs),
    /// One picture of what reshading does to a photo on a board's outermost views.
    #[command(long_about = SHEET_ABOUT)]
    Sheet(SheetArgs),
    /// Weave views (a directory of view_00.png …, or a quilt) into a panel frame.
    Weave(WeaveArgs),
    /// List the built-in boards.
    Boards,
    /// Convert photos for a gallery: one output folder each, skipping finished ones.
    #[command(long_about = reshader::device::gallery::cli::CONVERT_ABOUT)]
    Convert(reshader::device::gallery::cli::ConvertArgs),
    /// Convert photos as they appear in a folder, until SIGINT/SIGTERM.
    #[command(long_about = reshader::device::gallery::cli::WATCH_ABOUT)]
    Watch(reshader::device::gallery::cli::WatchArgs),
    /// Show a live camera on the panel: capture, views, weave, framebuffer or PNGs.
    #[command(long_about = reshader::device::capture::live::LIVE_ABOUT)]
    Live(reshader::device::capture::live::LiveArgs),
    /// Score relocation methods against rendered novel views (Table 1) and write contact sheets.
    #[command(long_about = reshader::eval::relocation::EVAL_ABOUT)]
    EvalRelocation(reshader::eval::relocation::EvalArgs),
    /// Time photo-to-frame conversion stage by stage against onnxruntime and the naive network.
    #[command(long_about = reshader::eval::bench::BENCH_ABOUT)]
    Bench(reshader::eval::bench::BenchArgs),
}

const RENDER_ABOUT: &str = "\
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

const RESHADE_ABOUT: &str = "\
Reshade the photo as seen from --camera, keeping the input camera's frame: the pixels
stay where they are and only their shading changes (highlights slide). With --model none
the photo comes back unchanged.

Examples:
  reshader reshade photo.jpg --camera 0.1,0,0 --out reshaded.png
  reshader reshade photo.jpg --depth depth.npy --camera 0.1,0,0 --out reshaded.png";

const SHEET_ABOUT: &str = "\
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

const VIEW_ABOUT: &str = "\
Render the novel view from --camera: reshade (unless --no-reshade), then relocate the
pixels with the depth. The projection is sheared so the zero-parallax plane (--focus)
stays put, as in `render`: for a photo of the board's view size, a render's view k
equals `view` with run.json's camera k.

Examples:
  reshader view photo.jpg --camera -0.2,0,0 --out view.exr
  reshader view photo.jpg --depth depth.npy --camera -0.2,0,0 --out view.exr";

#[derive(Args)]
struct SceneArgs {
    /// The photo (JPEG or PNG).
    photo: PathBuf,
    /// Where depth comes from: auto (the depth the photo carries, else the depth network),
    /// network, embedded (an error if the photo has none), or a depth file: .npy
    /// (float32/float16/uint16), 16-bit .png (thousandths of a unit), .pfm or .exr.
    #[arg(long, default_value = "auto", value_name = "FILE|auto|...")]
    depth: DepthInput,
    /// How to read a depth file: depth in scene units, or relative disparity (larger =
    /// nearer), normalised so the scene spans depth 1 to 5 units [default: depth].
    #[arg(long, value_enum)]
    depth_kind: Option<DepthKind>,
    /// Holes in a depth file (0, NaN or infinite values, where a sensor or renderer had
    /// no depth): refuse the file, put them at the farthest depth (far: skies), or fill
    /// them from their neighbours, following the photo's colour edges [default: refuse].
    #[arg(long, value_enum)]
    depth_holes: Option<HolePolicy>,
    /// Horizontal field of view in degrees [default: from EXIF 35 mm focal length, else 45].
    #[arg(long, allow_negative_numbers = true)]
    fov: Option<f64>,
    /// Depth of the zero-parallax plane, in depth-map units [default: robust middle depth].
    #[arg(long, allow_negative_numbers = true)]
    focus: Option<f64>,
    #[command(flatten)]
    reshade: reshader::reshade::net::cli::ReshadeArgs,
    #[command(flatten)]
    estimate: EstimateArgs,
}

impl SceneArgs {
    /// The depth file, or an estimator (the network is loaded only when used).
    fn scene_depth(&self) -> Result<SceneDepth> {
        match &self.depth {
            DepthInput::File(path) => Ok(SceneDepth::File {
                path: path.clone(),
                kind: self.depth_kind.unwrap_or(DepthKind::Depth),
                holes: self.depth_holes.unwrap_or_default(),
            }),
            DepthInput::Estimate(_) if self.depth_kind.is_some() => Err(anyhow::anyhow!(
                "--depth-kind says how to read a depth file; give the file with --depth FILE"
            )),
            DepthInput::Estimate(_) if self.depth_holes.is_some() => Err(anyhow::anyhow!(
                "--depth-holes says what to do with holes in a depth file; give the file \
                 with --depth FILE"
            )),
            DepthInput::Estimate(source) => Ok(SceneDepth::Estimate(Arc::new(
                self.estimate
                    .estimator(*source)
                    .map_err(anyhow::Error::msg)?,
            ))),
        }
    }
}

#[derive(Args)]
struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    relocate: RelocateArgs,
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long)]
    board: String,
    /// Per-unit calibration in Looking-Glass visual.json form; overrides the board's values.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Scales the camera baseline: 1 spans the board's view cone, 0 is flat [default: the
    /// largest value (at most 1) that keeps the outermost views' parallax within 3% of the
    /// view width].
    #[arg(long, allow_negative_numbers = true)]
    depthiness: Option<f64>,
    /// Scales the baseline of the cameras each view is reshaded for, as --depthiness scales
    /// the views' [default: the widest, at most 1, that keeps the outermost ones within the
    /// reach of the reshading model's training data, and at least --depthiness].
    #[arg(long, allow_negative_numbers = true)]
    shading_depthiness: Option<f64>,
    #[command(flatten)]
    filter: FilterArgs,
    /// Write only these products (comma-separated); run.json is always written.
    #[arg(long, value_enum, value_delimiter = ',')]
    only: Vec<Product>,
    /// The two views of sbs.png, as LEFT,RIGHT [default: outermost].
    #[arg(long, value_parser = parse_pair)]
    sbs_pair: Option<(usize, usize)>,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct SingleViewArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Novel camera centre TX,TY,TZ in the input camera's frame (OpenCV: x right, y down,
    /// z forward), in depth-map units.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    camera: [f64; 3],
    /// Output image: .png (8-bit), .exr or .npy (float).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct ViewArgs {
    #[command(flatten)]
    single: SingleViewArgs,
    /// Skip reshading: relocate the photo's own colours.
    #[arg(long)]
    no_reshade: bool,
    #[command(flatten)]
    relocate: RelocateArgs,
}

#[derive(Args)]
struct SheetArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    relocate: RelocateArgs,
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long, default_value = "looking-glass-go")]
    board: String,
    /// Scales the camera baseline, as `render --depthiness`.
    #[arg(long, allow_negative_numbers = true)]
    depthiness: Option<f64>,
    /// Scales the baseline of the cameras each view is reshaded for, as --depthiness scales
    /// the views' [default: the widest, at most 1, that keeps the outermost ones within the
    /// reach of the reshading model's training data, and at least --depthiness].
    #[arg(long, allow_negative_numbers = true)]
    shading_depthiness: Option<f64>,
    /// Output image (.png).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct WeaveArgs {
    /// A directory holding view_00.png … view_{N-1}.png, or a quilt image: its layout
    /// from its PNG metadata, else from its name (…_qs8x6a0.75.png).
    input: PathBuf,
    #[arg(long)]
    board: String,
    #[arg(long)]
    calibration: Option<PathBuf>,
    #[command(flatten)]
    filter: FilterArgs,
    /// Output panel image (.png).
    #[arg(long)]
    out: PathBuf,
}

/// How views are filtered when weaving; each option overrides the board's `[filter]`.
#[derive(Args)]
struct FilterArgs {
    /// Subpixels between view centres: the nearest view, a linear mix of the two nearest,
    /// or a Gaussian over the three nearest [default: the board's, else nearest].
    #[arg(long, value_enum)]
    blend: Option<BlendArg>,
    /// Darken this fraction of the view cone at each end (0 to 0.5), so that the jump
    /// where the cone wraps shows as a dark seam [default: the board's, else 0].
    #[arg(long, value_name = "FRACTION")]
    dim_edges: Option<f64>,
}

impl FilterArgs {
    fn apply(&self, board: &mut Board) -> Result<()> {
        let mut filter = board.filter();
        if let Some(blend) = self.blend {
            filter.blend = blend.into();
        }
        if let Some(dim) = self.dim_edges {
            filter.dim_edges = dim;
        }
        Ok(board.set_filter(filter)?)
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum BlendArg {
    Nearest,
    Linear,
    Gaussian,
}

impl From<BlendArg> for Blend {
    fn from(b: BlendArg) -> Self {
        match b {
            BlendArg::Nearest => Blend::Nearest,
            BlendArg::Linear => Blend::Linear,
            BlendArg::Gaussian => Blend::Gaussian,
        }
    }
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected TX,TY,TZ (three numbers), got '{s}'"));
    };
    let num = |t: &str| {
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("'{t}' is not a finite number"))
    };
    Ok([num(x)?, num(y)?, num(z)?])
}

fn parse_pair(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected LEFT,RIGHT view indices, got '{s}'"))?;
    let idx = |t: &str| {
        t.trim()
            .parse::<usize>()
            .map_err(|_| format!("'{t}' is not a view index"))
    };
    Ok((idx(a)?, idx(b)?))
}

#[global_allocator]
static ALLOCATOR: reshader::io::limits::Allocator = reshader::io::limits::Allocator;

fn main() -> ExitCode {
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => log::LevelFilter::Warn,
        1 => log::LevelFilter::Info,
        _ => log::LevelFilter::Debug,
    };
    env_logger::Builder::new()
        .filter_level(level)
        .format_timestamp(None)
        .init();
    reshader::pipeline::progress::set_verbose(cli.verbose > 0);
    reshader::io::limits::set_max_memory(cli.max_memory);
    if let Err(e) = reshader::io::limits::apply_process_limit(cli.max_memory) {
        log::warn!("cannot set the memory limit of the process: {e}");
    }
    reshader::io::limits::install_panic_hook();
    reshader::io::limits::install_abort_report();
    ExitCode::from(reshader::io::limits::run_guarded(|| run(cli.command)))
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Render(args) => render(args),
        Command::Depth(args) => {
            println!("{}", reshader::depth::net::cli::run_depth(&args)?);
            Ok(())
        }
        Command::Reshade(args) => reshade(args),
        Command::View(args) => view(args),
        Command::Sheet(args) => sheet(args),
        Command::Weave(args) => weave(args),
        Command::Convert(args) => Ok(reshader::device::gallery::cli::run_convert(&args)?),
        Command::Watch(args) => Ok(reshader::device::gallery::cli::run_watch(&args)?),
        Command::Live(args) => Ok(reshader::device::capture::live::run_live(&args)?),
        Command::EvalRelocation(args) => {
            reshader::eval::relocation::run(&args)?;
            Ok(())
        }
        Command::Bench(args) => {
            let command: Vec<String> = std::env::args().collect();
            reshader::eval::bench::main(&args, &command.join(" "))?;
            Ok(())
        }
        Command::Boards => {
            list_boards();
            Ok(())
        }
    }
}

/// Refuses a `--model` that names the wrong kind of file before anything loads.
fn check_model(args: &reshader::reshade::net::cli::ReshadeArgs) -> Result<()> {
    if let Some(model) = reshader::pipeline::preflight::chosen_reshade_model(args.model.as_deref())
    {
        reshader::pipeline::preflight::check_model_path("--model", &model)?;
    }
    Ok(())
}

fn render(args: RenderArgs) -> Result<()> {
    // Everything that can be checked without the photo is checked before any work.
    output::check_output_dir(&args.out)?;
    for d in [args.depthiness, args.shading_depthiness]
        .into_iter()
        .flatten()
    {
        reshader::views::check_depthiness(d)?;
    }
    check_model(&args.scene.reshade)?;
    let mut board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    args.filter.apply(&mut board)?;
    // The memory the sizes imply, before anything large is allocated. A photo whose
    // header cannot be read is reported by loading it; its board still counts.
    let photo_size = reshader::io::photo::header_size(&args.scene.photo).unwrap_or((1, 1));
    let size = reshader::pipeline::preflight::render_size(
        photo_size,
        &board,
        &args.only,
        &args.scene.reshade,
        !matches!(args.scene.depth, DepthInput::File(_)),
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
    let reshader = args.scene.reshade.build()?;
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
    let record = pipeline::render(&opts, &*reshader, &*args.relocate.build())?;
    println!(
        "{}: {} views, wrote {} files to {}",
        opts.board.name(),
        record.views.len(),
        record.outputs.len(),
        opts.out_dir.display()
    );
    Ok(())
}

/// Refuses a single view at the photo's resolution that would not fit --max-memory.
fn check_single_view_memory(args: &SceneArgs, reshading: bool) -> Result<()> {
    let Some(photo) = reshader::io::photo::header_size(&args.photo) else {
        return Ok(());
    };
    let size = reshader::pipeline::preflight::single_view_size(
        photo,
        reshading.then_some(&args.reshade),
        !matches!(args.depth, DepthInput::File(_)),
    );
    reshader::pipeline::preflight::check_memory(
        format!("a view of a {}x{} photo", photo.0, photo.1),
        &reshader::pipeline::preflight::estimate(&size),
        reshader::pipeline::preflight::VIEW_HINT,
    )?;
    Ok(())
}

fn load_scene(args: &SceneArgs) -> Result<Scene> {
    let depth = args.scene_depth()?;
    let mut timings = reshader::io::record::Timings::default();
    Ok(Scene::load(&args.photo, &depth, args.fov, &mut timings)?)
}

fn reshade(args: SingleViewArgs) -> Result<()> {
    output::FileFormat::require(&args.out, output::IMAGE_FORMATS)?;
    output::check_output_file(&args.out)?;
    check_model(&args.scene.reshade)?;
    check_single_view_memory(&args.scene, true)?;
    let scene = load_scene(&args.scene)?;
    let req = ViewRequest {
        scene: &scene,
        camera: args.camera,
        focus: args.scene.focus,
    };
    let reshader = args.scene.reshade.build()?;
    let image = pipeline::reshade_photo(&req, &*reshader)?;
    pipeline::write_image(&args.out, &image)?;
    Ok(())
}

fn view(args: ViewArgs) -> Result<()> {
    let single = args.single;
    output::FileFormat::require(&single.out, output::IMAGE_FORMATS)?;
    output::check_output_file(&single.out)?;
    if !args.no_reshade {
        check_model(&single.scene.reshade)?;
    }
    check_single_view_memory(&single.scene, !args.no_reshade)?;
    let scene = load_scene(&single.scene)?;
    let req = ViewRequest {
        scene: &scene,
        camera: single.camera,
        focus: single.scene.focus,
    };
    let reshader = if args.no_reshade {
        None
    } else {
        Some(single.scene.reshade.build()?)
    };
    let reshader = reshader
        .as_deref()
        .map(|r| r as &dyn reshader::reshade::Reshader);
    let image = pipeline::render_view(&req, reshader, &*args.relocate.build())?;
    pipeline::write_image(&single.out, &image)?;
    Ok(())
}

fn sheet(args: SheetArgs) -> Result<()> {
    output::FileFormat::require(&args.out, &[output::FileFormat::Png])?;
    output::check_output_file(&args.out)?;
    check_model(&args.scene.reshade)?;
    check_single_view_memory(&args.scene, true)?;
    let board = pipeline::load_board(&args.board, None)?;
    for d in [args.depthiness, args.shading_depthiness]
        .into_iter()
        .flatten()
    {
        reshader::views::check_depthiness(d)?;
    }
    let scene = load_scene(&args.scene)?;
    let reshader = args.scene.reshade.build()?;
    let relocator = args.relocate.build();
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

fn weave(args: WeaveArgs) -> Result<()> {
    output::FileFormat::require(&args.out, &[output::FileFormat::Png])?;
    output::check_output_file(&args.out)?;
    let mut board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    args.filter.apply(&mut board)?;
    reshader::pipeline::preflight::check_memory(
        format!("weaving for {}", board.name()),
        &reshader::pipeline::preflight::weave_estimate(&board),
        "",
    )?;
    let panel = if args.input.is_dir() {
        pipeline::weave_dir(&args.input, &board)?
    } else {
        reshader::io::quilt_file::weave(&args.input, &board)?
    };
    let bytes = output::encode_png(&args.out, &panel)?;
    output::write_atomic(&args.out, &bytes)?;
    Ok(())
}

fn list_boards() {
    for name in Board::builtin_names() {
        match Board::builtin(name) {
            Ok(b) => {
                let (w, h) = b.panel_size();
                let (vw, vh) = b.view_size();
                println!(
                    "{name:<26} {w}x{h}, {} views of {vw}x{vh}, {}° cone — {}",
                    b.views(),
                    b.view_cone_deg(),
                    b.description()
                );
            }
            Err(e) => println!("{name:<26} (invalid: {e})"),
        }
    }
}
