//! The `reshader` command: argument parsing, help texts, printing and signals, one file
//! per subcommand; the work is the `reshader` library's.

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

mod args;
mod bench;
mod depth;
mod eval_relocation;
mod gallery;
mod live;
mod render;
mod sheet;
mod signals;
mod view;
mod weave;

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
    #[command(long_about = render::RENDER_ABOUT)]
    Render(render::RenderArgs),
    /// Estimate depth for a photo: the depth it carries, or the depth network.
    #[command(long_about = depth::DEPTH_ABOUT)]
    Depth(depth::DepthArgs),
    /// Reshade the photo for a novel camera, in the input camera's frame.
    #[command(long_about = view::RESHADE_ABOUT)]
    Reshade(view::SingleViewArgs),
    /// Render the novel view from one camera position.
    #[command(long_about = view::VIEW_ABOUT)]
    View(view::ViewArgs),
    /// One picture of what reshading does to a photo on a board's outermost views.
    #[command(long_about = sheet::SHEET_ABOUT)]
    Sheet(sheet::SheetArgs),
    /// Weave views (a directory of view_00.png …, or a quilt) into a panel frame.
    Weave(weave::WeaveArgs),
    /// List the built-in boards.
    Boards,
    /// Convert photos for a gallery: one output folder each, skipping finished ones.
    #[command(long_about = gallery::CONVERT_ABOUT)]
    Convert(gallery::ConvertArgs),
    /// Convert photos as they appear in a folder, until SIGINT/SIGTERM.
    #[command(long_about = gallery::WATCH_ABOUT)]
    Watch(gallery::WatchArgs),
    /// Show a live camera on the panel: capture, views, weave, framebuffer or PNGs.
    #[command(long_about = live::LIVE_ABOUT)]
    Live(live::LiveArgs),
    /// Score relocation methods against rendered novel views (Table 1) and write contact sheets.
    #[command(long_about = eval_relocation::EVAL_ABOUT)]
    EvalRelocation(eval_relocation::EvalArgs),
    /// Time photo-to-frame conversion stage by stage against onnxruntime and the naive network.
    #[command(long_about = bench::BENCH_ABOUT)]
    Bench(bench::BenchArgs),
}

#[global_allocator]
static ALLOCATOR: reshader::io::limits::Allocator = reshader::io::limits::Allocator;

fn main() -> ExitCode {
    reshader::io::limits::share_one_heap();
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
        Command::Render(args) => render::render(args),
        Command::Depth(args) => depth::depth(&args),
        Command::Reshade(args) => view::reshade(args),
        Command::View(args) => view::view(args),
        Command::Sheet(args) => sheet::sheet(args),
        Command::Weave(args) => weave::weave(args),
        Command::Convert(args) => gallery::convert(&args),
        Command::Watch(args) => gallery::watch(&args),
        Command::Live(args) => live::live(&args),
        Command::EvalRelocation(args) => eval_relocation::eval_relocation(&args),
        Command::Bench(args) => bench::bench(&args),
        Command::Boards => {
            weave::list_boards();
            Ok(())
        }
    }
}
