//! The `convert` and `watch` subcommands: their arguments and the render pipeline as a
//! [`Converter`].

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use interleave::Board;

use super::watch::{watch, WatchOptions};
use super::{convert_batch, ConvertReport, Converter, FnConverter, OutLayout, PhotoReport};
use crate::depth::holes::HolePolicy;
use crate::depth::net::cli::EstimateArgs;
use crate::depth::net::{DepthEstimator, DepthNetError, DepthSource};
use crate::depth::DepthKind;
use crate::pipeline::progress::Progress;
use crate::pipeline::{self, Product, RenderOptions, SceneDepth};
use crate::relocate::RelocateArgs;
use crate::reshade::net::cli::ReshadeArgs;
use crate::reshade::net::NetError;
use crate::reshade::Reshader;

/// Depth files looked for beside a photo, in order: `NAME_depth.EXT` holds depth in
/// scene units, `NAME_disparity.EXT` relative disparity. Without one, the photo's
/// embedded depth or the depth network is used.
pub(crate) const DEPTH_SIDECARS: &[(&str, DepthKind)] = &[
    ("_depth", DepthKind::Depth),
    ("_disparity", DepthKind::Disparity),
];
pub(crate) const DEPTH_EXTENSIONS: &[&str] = &["npy", "png", "pfm", "exr"];

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
    #[error("{0}")]
    Options(String),
    #[error(transparent)]
    Output(#[from] crate::io::output::OutputError),
    #[error(transparent)]
    ModelPath(#[from] crate::pipeline::preflight::ModelPathError),
    #[error(transparent)]
    Memory(#[from] crate::pipeline::preflight::OverBudget),
    #[error("{failed} of {total} photos failed")]
    SomeFailed { failed: usize, total: usize },
    #[error("cannot install the SIGINT/SIGTERM handler: {0}")]
    Signal(std::io::Error),
}

/// Settings shared by `convert` and `watch`.
#[derive(clap::Args, Debug)]
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
    #[arg(long, value_enum, value_delimiter = ',')]
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
    #[arg(long, value_enum, default_value_t = HolePolicy::Refuse)]
    pub depth_holes: HolePolicy,
    #[command(flatten)]
    pub relocate: RelocateArgs,
    #[command(flatten)]
    pub estimate: EstimateArgs,
    #[command(flatten)]
    pub reshade: ReshadeArgs,
}

#[derive(clap::Args, Debug)]
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

#[derive(clap::Args, Debug)]
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
pub fn run_convert(args: &ConvertArgs) -> Result<(), GalleryError> {
    let (photos, passed_over) = collect_photos(&args.photos);
    for (path, why) in &passed_over {
        log::info!("not converting {}: {why}", path.display());
    }
    if photos.is_empty() && !passed_over.is_empty() {
        let (path, why) = &passed_over[0];
        return Err(GalleryError::Options(format!(
            "none of the inputs is a photo to convert ({} passed over; {}: {why})",
            passed_over.len(),
            path.display()
        )));
    }
    let converter = pipeline_converter(&args.gallery)?;
    let layout = layout(&args.gallery);
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
        Err(GalleryError::SomeFailed {
            failed: summary.failed,
            total: photos.len(),
        })
    }
}

/// The photos among `convert`'s inputs, in order, and the inputs passed over with the
/// reason. A folder stands for the photos directly in it (sorted by name); what a
/// batch over `DIR/*` also catches is passed over: depth sidecars of photos beside
/// them, the batch's own `NAME.reshader/` output folders, files that are not JPEG or
/// PNG by name, and special files (FIFOs, sockets, devices), which are never opened.
/// A path that does not exist stays in, to fail with its own message.
pub fn collect_photos(inputs: &[PathBuf]) -> (Vec<PathBuf>, Vec<(PathBuf, String)>) {
    let (mut photos, mut passed) = (Vec::new(), Vec::new());
    for input in inputs {
        let Ok(meta) = std::fs::metadata(input) else {
            photos.push(input.clone());
            continue;
        };
        if meta.is_dir() {
            if is_output_dir(input) {
                passed.push((input.clone(), "a reshader output folder".into()));
                continue;
            }
            let Ok(entries) = std::fs::read_dir(input) else {
                photos.push(input.clone());
                continue;
            };
            let mut inside: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
            inside.sort();
            for path in inside {
                match std::fs::metadata(&path) {
                    Ok(m) if m.is_dir() => {}
                    Ok(m) => match pass_over(&path, &m) {
                        Some(why) => passed.push((path, why)),
                        None => photos.push(path),
                    },
                    Err(_) => {}
                }
            }
            continue;
        }
        match pass_over(input, &meta) {
            Some(why) => passed.push((input.clone(), why)),
            None => photos.push(input.clone()),
        }
    }
    (photos, passed)
}

/// Why a file among the inputs is not a photo to convert, if it is not.
fn pass_over(path: &Path, meta: &std::fs::Metadata) -> Option<String> {
    if !meta.is_file() {
        return Some(crate::io::limits::not_a_regular_file(meta).to_string());
    }
    if let Some(photo) = photo_of_sidecar(path) {
        return Some(format!("the depth sidecar of {}", photo.display()));
    }
    let name = path.file_name()?.to_string_lossy();
    if name.starts_with('.') {
        return Some("a hidden file".into());
    }
    let is_photo = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| PHOTO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
    (!is_photo).then(|| "not a JPEG or PNG (by its name)".into())
}

/// Photo file extensions `convert` takes from folders and globs.
const PHOTO_EXTENSIONS: &[&str] = &["jpg", "jpeg", "png"];

/// The photo beside `path` whose depth sidecar it is (`a_depth.png` beside `a.jpg`).
fn photo_of_sidecar(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?.to_str()?;
    let (stem, ext) = name.rsplit_once('.')?;
    if !DEPTH_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()) {
        return None;
    }
    let photo_stem = DEPTH_SIDECARS
        .iter()
        .find_map(|(suffix, _)| stem.strip_suffix(suffix))?;
    PHOTO_EXTENSIONS
        .iter()
        .flat_map(|e| [e.to_string(), e.to_ascii_uppercase()])
        .map(|e| path.with_file_name(format!("{photo_stem}.{e}")))
        .find(|p| p.is_file())
}

/// Whether `dir` is an output folder of `convert`/`render`: named `NAME.reshader` or
/// holding a done-marker or a run.json.
fn is_output_dir(dir: &Path) -> bool {
    dir.file_name()
        .is_some_and(|n| n.to_string_lossy().ends_with(super::BESIDE_SUFFIX))
        || dir.join(super::DONE_MARKER).is_file()
        || dir.join("run.json").is_file()
}

/// `reshader watch`: runs until SIGINT or SIGTERM.
pub fn run_watch(args: &WatchArgs) -> Result<(), GalleryError> {
    let converter = pipeline_converter(&args.gallery)?;
    let stop = stop_on_signals().map_err(GalleryError::Signal)?;
    let opts = WatchOptions {
        settle: Duration::from_millis(args.settle_ms),
        rescan: Duration::from_millis(args.rescan_ms.max(10)),
        inotify: !args.poll,
        progress: Progress::start(0, "photos", args.gallery.json),
        ..WatchOptions::new(&args.dir, layout(&args.gallery))
    };
    opts.progress
        .set_message(format!("watching {}", args.dir.display()));
    let json = args.gallery.json;
    let summary = watch(&opts, &converter, &stop, |r| {
        opts.progress.suspend(|| print_report(r, json))
    })?;
    opts.progress.finish();
    eprintln!("stopped: {summary}");
    Ok(())
}

/// A flag set by the first SIGINT or SIGTERM; a second one exits at once.
pub fn stop_on_signals() -> std::io::Result<Arc<AtomicBool>> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        // Registered first, so it sees the flag as the previous signal left it.
        signal_hook::flag::register_conditional_shutdown(signal, 130, Arc::clone(&stop))?;
        signal_hook::flag::register(signal, Arc::clone(&stop))?;
    }
    Ok(stop)
}

fn layout(args: &GalleryArgs) -> OutLayout {
    match &args.out {
        Some(dir) => OutLayout::Under(dir.clone()),
        None => OutLayout::BesidePhoto,
    }
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

/// The render pipeline as a converter: the board, the depth network and the reshading
/// network are loaded here, once, and shared by every photo (a bad --depth-model or
/// --model fails before any photo).
pub fn pipeline_converter(args: &GalleryArgs) -> Result<impl Converter, GalleryError> {
    if let Some(out) = &args.out {
        crate::io::output::check_output_dir(out)?;
    }
    if let Some(model) =
        crate::pipeline::preflight::chosen_reshade_model(args.reshade.model.as_deref())
    {
        crate::pipeline::preflight::check_model_path("--model", &model)?;
    }
    let board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    let estimator = args
        .estimate
        .estimator(DepthSource::Auto)
        .map_err(GalleryError::Options)?;
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
        move |photo: &Path, out_dir: &Path| -> Result<ConvertReport, String> {
            crate::io::output::check_output_dir(out_dir).map_err(|e| e.to_string())?;
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
                )
                .map_err(|e| e.to_string())?;
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
            let record =
                pipeline::render(&opts, &*reshader, &*relocator).map_err(|e| e.to_string())?;
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
    args: &GalleryArgs,
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
        args.depth_holes.name(),
        estimator.describe(),
        reshader.description(),
        args.relocate.build().description()
    )
}

/// The depth map beside `photo`, and how to read it.
pub fn find_depth(photo: &Path) -> Option<(PathBuf, DepthKind)> {
    let stem = photo
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    for (suffix, kind) in DEPTH_SIDECARS {
        for ext in DEPTH_EXTENSIONS {
            let candidate = photo.with_file_name(format!("{stem}{suffix}.{ext}"));
            if candidate.is_file() {
                return Some((candidate, *kind));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_sidecars_are_found_by_name_and_kind() {
        let dir = tempfile::tempdir().unwrap();
        let photo = dir.path().join("img.jpg");
        assert_eq!(find_depth(&photo), None);
        std::fs::write(dir.path().join("img_disparity.png"), b"").unwrap();
        assert_eq!(
            find_depth(&photo).unwrap(),
            (dir.path().join("img_disparity.png"), DepthKind::Disparity)
        );
        std::fs::write(dir.path().join("img_depth.exr"), b"").unwrap();
        assert_eq!(find_depth(&photo).unwrap().1, DepthKind::Depth);
    }
}
