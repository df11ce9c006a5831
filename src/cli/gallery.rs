//! `reshader convert` and `reshader watch`: a gallery's photos converted, in a batch or
//! as they appear.

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use clap::Args;

use reshader::depth::holes::HolePolicy;
use reshader::device::gallery::photos::collect_photos;
use reshader::device::gallery::render::{pipeline_converter, GalleryConfig};
use reshader::device::gallery::watch::{watch as gallery_watch, WatchOptions};
use reshader::device::gallery::{convert_batch, PhotoReport};
use reshader::pipeline::progress::Progress;
use reshader::pipeline::Product;

use crate::args::{keyword, EstimateArgs, RelocateArgs, ReshadeArgs};
use crate::signals::stop_on_signals;

/// Settings shared by `convert` and `watch`.
#[derive(Args, Debug)]
pub struct GalleryArgs {
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long)]
    pub board: String,
    /// Per-unit calibration in Looking-Glass visual.json form.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Put each photo's outputs in OUT/NAME/ instead of NAME.reshader/ beside the photo.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write only these products (comma-separated); run.json is always written.
    #[arg(long, value_parser = keyword::<Product>(), value_delimiter = ',')]
    pub only: Vec<Product>,
    /// Scales the camera baseline: 1 spans the board's view cone, 0 is flat
    /// [default: as much as the parallax budget allows, as `render` does].
    #[arg(long)]
    pub depthiness: Option<f64>,
    /// Print one JSON object per photo on stdout (status, outputs, timings_ms, error).
    #[arg(long)]
    pub json: bool,
    /// Holes in depth sidecars (0, NaN or infinite values): refuse the photo, put them at
    /// the farthest depth (far), or fill them from their neighbours (fill).
    #[arg(long, value_parser = keyword::<HolePolicy>(), default_value = "refuse")]
    pub depth_holes: HolePolicy,
    #[command(flatten)]
    pub relocate: RelocateArgs,
    #[command(flatten)]
    pub estimate: EstimateArgs,
    #[command(flatten)]
    pub reshade: ReshadeArgs,
}

#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// Photos (JPEG or PNG), or folders of them (not recursive). Depth sidecars,
    /// NAME.reshader/ output folders, other files and special files among them are
    /// passed over (-v lists them). Depth: NAME_depth.{npy,png,pfm,exr} (scene units) or
    /// NAME_disparity.{npy,png,pfm,exr} (relative disparity) beside the photo if present,
    /// else the depth the photo carries, else the depth network.
    #[arg(required = true)]
    pub photos: Vec<PathBuf>,
    #[command(flatten)]
    pub gallery: GalleryArgs,
    /// Convert again even when the outputs are up to date.
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct WatchArgs {
    /// Folder to watch (not recursive); photos already in it are converted first.
    pub dir: PathBuf,
    #[command(flatten)]
    pub gallery: GalleryArgs,
    /// Milliseconds a file must stay unchanged before it counts as complete, when the
    /// OS does not report its writer closing it.
    #[arg(long, default_value_t = 2000)]
    pub settle_ms: u64,
    /// Milliseconds between rescans of the folder (the only mechanism with --poll).
    #[arg(long, default_value_t = 1000)]
    pub rescan_ms: u64,
    /// Poll the folder instead of using inotify.
    #[arg(long)]
    pub poll: bool,
}

impl GalleryArgs {
    fn config(&self) -> GalleryConfig {
        GalleryConfig {
            board: self.board.clone(),
            calibration: self.calibration.clone(),
            out: self.out.clone(),
            only: self.only.clone(),
            depthiness: self.depthiness,
            depth_holes: self.depth_holes,
            relocate: self.relocate.config(),
            depth: self.estimate.config(),
            reshade: self.reshade.config(),
        }
    }
}

pub const CONVERT_ABOUT: &str = "\
Convert photos into the board's panel frame (and quilt, views, side-by-side pair), for a
camera app's gallery or a CI job.

Each photo's outputs go to NAME.reshader/ beside it, or OUT/NAME/ with --out, written
atomically. A photo converted before with the same bytes and settings is skipped (its
.reshader-done.json records both) unless --force. One bad photo never stops the batch;
the exit code is 0 only if every photo succeeded.

Depth per photo: a sidecar NAME_depth.{npy,png,pfm,exr} (scene units) or
NAME_disparity.{…} (relative disparity) beside it when there is one, else the depth the
photo carries (GDepth / Dynamic Depth), else the depth network. Each run.json says
which (inputs.depth.source).

Every view is reshaded with the reshading model (--model, default models/reshade or
$RESHADER_MODEL; --model none keeps the photo's shading); run.json names it (reshade).
The depth and reshading networks are loaded once, before the first photo: a bad model
fails the command before any photo is touched. Changing the model, its precision or the
reshading options reconverts photos converted before.

A folder stands for the photos in it; depth sidecars, the NAME.reshader/ output
folders, files that are not JPEG or PNG and special files (FIFOs, devices) among the
inputs are passed over and never opened (-v lists them), so `convert DIR/*` and
`convert DIR` can be run again and again.

Examples:
  reshader convert ~/DCIM/*.jpg --board looking-glass-go
  reshader convert ~/DCIM --board looking-glass-go
  reshader convert a.jpg b.jpg --board looking-glass-portrait --out panels/ --json";

pub const WATCH_ABOUT: &str = "\
Convert photos as they appear in a folder: inotify (or polling with --poll) notices
them, a file is converted once its writer closed it or it stopped changing, and photos a
previous run finished are skipped. Stops cleanly on SIGINT/SIGTERM (a second signal
exits at once). Depth and reshading as for convert: the networks are loaded once, at
start, and a bad --model or --depth-model fails before the folder is read.

Example:
  reshader watch ~/DCIM/Camera --board looking-glass-go --out ~/lightfield --json";

/// `reshader convert`.
pub fn convert(args: &ConvertArgs) -> Result<()> {
    let (photos, passed_over) = collect_photos(&args.photos);
    for (path, why) in &passed_over {
        log::info!("not converting {}: {why}", path.display());
    }
    if photos.is_empty() && !passed_over.is_empty() {
        let (path, why) = &passed_over[0];
        anyhow::bail!(
            "none of the inputs is a photo to convert ({} passed over; {}: {why})",
            passed_over.len(),
            path.display()
        );
    }
    let config = args.gallery.config();
    let converter = pipeline_converter(&config)?;
    let layout = config.layout();
    let json = args.gallery.json;
    let progress = Progress::start(photos.len() as u64, "photos", json);
    let summary = convert_batch(&photos, &layout, args.force, &converter, |r| {
        progress.suspend(|| print_report(r, json));
        progress.inc(1);
    });
    progress.finish();
    eprintln!("{summary}");
    if summary.all_ok() {
        Ok(())
    } else {
        anyhow::bail!("{} of {} photos failed", summary.failed, photos.len())
    }
}

/// `reshader watch`: runs until SIGINT or SIGTERM.
pub fn watch(args: &WatchArgs) -> Result<()> {
    let config = args.gallery.config();
    let converter = pipeline_converter(&config)?;
    let stop = stop_on_signals()?;
    let opts = WatchOptions {
        settle: Duration::from_millis(args.settle_ms),
        rescan: Duration::from_millis(args.rescan_ms.max(10)),
        inotify: !args.poll,
        progress: Progress::start(0, "photos", args.gallery.json),
        ..WatchOptions::new(&args.dir, config.layout())
    };
    opts.progress
        .set_message(format!("watching {}", args.dir.display()));
    let json = args.gallery.json;
    let summary = gallery_watch(&opts, &converter, &stop, |r| {
        opts.progress.suspend(|| print_report(r, json))
    })?;
    opts.progress.finish();
    eprintln!("stopped: {summary}");
    Ok(())
}

fn print_report(report: &PhotoReport, json: bool) {
    let line = if json {
        report.json_line()
    } else {
        report.to_string()
    };
    let mut out = std::io::stdout().lock();
    // A closed stdout (e.g. piped into `head`) must not stop the conversions.
    let _ = writeln!(out, "{line}").and_then(|()| out.flush());
}
