//! One photo converted for one board, stage by stage, the way `render` does it, with each
//! stage timed on its own.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;
use interleave::{Blend, Board, Weaver};

use crate::depth::DepthMap;
use crate::depth_net::{network_depth, StageOptions};
use crate::photo::{load_rgb8, SrgbImage};
use crate::relocate::{MeshWarp, Relocator};
use crate::reshade::TrainingFrame;
use crate::views::{robust_focus, Intrinsics, ViewRig};

use super::report::{Case, StageRow};
use super::{io_err, stage_stats, BenchError, Context};

/// Field of view assumed for every photo: the benchmark times, it does not judge geometry.
const HFOV_DEG: f64 = 45.0;

/// Writes the deterministic synthetic photo (the reshading benchmark's test scene) as a
/// JPEG, so that decoding it is part of the measurement like for a real photo.
pub fn write_synthetic_photo(dir: &Path, (w, h): (u32, u32)) -> Result<PathBuf, BenchError> {
    let (image, _) = crate::bench_reshade::test_scene(w, h);
    let path = dir.join(format!("synthetic-{w}x{h}.jpg"));
    let file = std::fs::File::create(&path).map_err(io_err(&path))?;
    let encoder =
        image::codecs::jpeg::JpegEncoder::new_with_quality(std::io::BufWriter::new(file), 90);
    image
        .to_rgb8()
        .write_with_encoder(encoder)
        .map_err(|e| BenchError::Io {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
    Ok(path)
}

type RunTimes = Vec<(&'static str, f64)>;

fn timed<T>(times: &mut RunTimes, stage: &'static str, f: impl FnOnce() -> T) -> T {
    let started = Instant::now();
    let out = f();
    times.push((stage, started.elapsed().as_secs_f64() * 1e3));
    out
}

/// One warm-up run (plans are built there), then `runs` timed runs.
pub fn run_case(
    ctx: &Context,
    label: &str,
    photo: &Path,
    board: &Board,
    runs: usize,
) -> Result<Case, BenchError> {
    let first = run_once(ctx, photo, board)?;
    let mut all = Vec::with_capacity(runs);
    for _ in 0..runs {
        all.push(run_once(ctx, photo, board)?.times);
    }
    let (rows, total) = stage_stats(&all);
    let (vw, vh) = board.view_size();
    let stages = rows
        .into_iter()
        .map(|(stage, time)| StageRow {
            stage: stage.into(),
            detail: detail(ctx, stage, board, &first),
            time,
        })
        .collect();
    Ok(Case {
        photo: label.into(),
        photo_size: first.photo_size,
        board: board.name().into(),
        views: board.views(),
        view_size: [vw, vh],
        stages,
        total,
        peak_rss_mib: None,
    })
}

struct Run {
    times: RunTimes,
    photo_size: [u32; 2],
    depth_input: (usize, usize),
    work_size: [u32; 2],
}

fn run_once(ctx: &Context, photo: &Path, board: &Board) -> Result<Run, BenchError> {
    let mut t = RunTimes::new();
    let (rgb, image) = timed(&mut t, "decode", || -> Result<_, BenchError> {
        let rgb = load_rgb8(photo)?;
        let image = SrgbImage::from_rgb8(&rgb);
        Ok((rgb, image))
    })?;
    let depth_input = ctx.depth.network_size(rgb.width(), rgb.height())?;
    let started = Instant::now();
    timed(&mut t, "depth", || ctx.depth.estimate(&rgb))?;
    let estimate_ms = started.elapsed().as_secs_f64() * 1e3;
    // network_depth runs the network again and then the rest of the depth stage; the
    // rest is its time minus the network's time just measured.
    let started = Instant::now();
    let (depth, _) = network_depth(&ctx.depth, &rgb, &StageOptions::default())?;
    let rest_ms = (started.elapsed().as_secs_f64() * 1e3 - estimate_ms).max(0.0);
    t.push(("depth refinement", rest_ms));
    let (vw, vh) = board.view_size();
    let fitted = timed(&mut t, "fit to view size", || fit(&image, &depth, vw, vh));
    let focus = robust_focus(&fitted.depth);
    let rig = ViewRig::new(board.views(), f64::from(board.view_cone_deg()), focus, 1.0)?;
    let cameras = rig.cameras(&fitted.reference);
    let frame = TrainingFrame::for_focus(focus);
    let training_depth = frame.depth(&fitted.depth);
    let prepared = timed(&mut t, "reshade encoder", || {
        ctx.reshader.prepare_photo(&fitted.image, &training_depth)
    })?;
    let centres: Vec<[f64; 3]> = cameras.iter().map(|c| frame.camera(c.centre)).collect();
    let colours = timed(&mut t, "reshade decoder × views", || {
        prepared.reshade_views(&centres)
    })?;
    let warp = MeshWarp::default();
    let views = timed(&mut t, "relocate (LDI render) × views", || {
        cameras
            .iter()
            .zip(&colours)
            .map(|(camera, c)| warp.render(c, &fitted.depth, &fitted.source, camera))
            .collect::<Result<Vec<_>, _>>()
    })?;
    let weaver = timed(&mut t, "weave table", || {
        Weaver::new(board, vw, vh, Blend::Nearest).with_threads(ctx.threads)
    });
    let panel = timed(&mut t, "weave", || {
        let rgb8: Vec<RgbImage> = views.iter().map(SrgbImage::to_rgb8).collect();
        weaver.weave(&rgb8)
    })?;
    let out = ctx.work_dir.0.join("panel.png");
    timed(&mut t, "encode/write", || -> Result<(), BenchError> {
        let bytes = crate::output::encode_png(&out, &panel)?;
        crate::output::write_atomic(&out, &bytes)?;
        Ok(())
    })?;
    Ok(Run {
        times: t,
        photo_size: [rgb.width(), rgb.height()],
        depth_input,
        work_size: [fitted.image.width(), fitted.image.height()],
    })
}

struct Fitted {
    image: SrgbImage,
    depth: DepthMap,
    source: Intrinsics,
    reference: Intrinsics,
}

/// Photo and depth shrunk to cover a view (never enlarged), as `render` fits them.
fn fit(image: &SrgbImage, depth: &DepthMap, vw: u32, vh: u32) -> Fitted {
    let (pw, ph) = (image.width(), image.height());
    let cover = (f64::from(vw) / f64::from(pw)).max(f64::from(vh) / f64::from(ph));
    let (fw, fh) = if cover < 1.0 {
        (
            ((f64::from(pw) * cover).ceil() as u32).max(1),
            ((f64::from(ph) * cover).ceil() as u32).max(1),
        )
    } else {
        (pw, ph)
    };
    let source = Intrinsics::from_hfov(fw, fh, HFOV_DEG);
    Fitted {
        image: image.resized(fw, fh),
        depth: depth.resized(fw as usize, fh as usize),
        source,
        reference: source.cover(vw, vh),
    }
}

fn detail(ctx: &Context, stage: &str, board: &Board, run: &Run) -> String {
    let views = board.views();
    let [ww, wh] = run.work_size;
    match stage {
        "decode" => "image crate decode to 8-bit RGB, then float sRGB".into(),
        "depth" => format!(
            "{} {} ({}), network input {}x{}",
            ctx.depth.manifest().name,
            ctx.depth.manifest().version,
            ctx.depth.manifest().precision,
            run.depth_input.0,
            run.depth_input.1
        ),
        "depth refinement" => {
            "upsample to the photo, edge-aware refinement, scene scaling (network_depth − depth)"
                .into()
        }
        "fit to view size" => format!("photo and depth resized to {ww}x{wh}"),
        "LDI build + inpainting" => "src/ldi has no LDI builder in this build".into(),
        "reshade encoder" if ctx.reshader.is_split() => format!("once per photo at {ww}x{wh}"),
        "reshade encoder" => {
            "single-graph model: only input preparation here, the whole network runs per view"
                .into()
        }
        "reshade decoder × views" => format!("{views} views at {ww}x{wh}"),
        "relocate (LDI render) × views" => {
            format!("{views} views by MeshWarp (depth-mesh rasterisation), the stand-in until the LDI renderer is built")
        }
        "weave table" => {
            "Weaver::new: subpixel→view table for the board (once per board and view size)".into()
        }
        "weave" => format!("views to 8-bit + subpixel weave, {} threads", ctx.threads),
        "encode/write" => "panel PNG encode + atomic write".into(),
        _ => String::new(),
    }
}
