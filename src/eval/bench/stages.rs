//! One photo converted for one board, stage by stage, the way `render` does it, with each
//! stage timed on its own.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;
use interleave::{Board, Weaver};

use crate::depth::net::{scene_depth, StageOptions};
use crate::io::photo::Photo;
use crate::io::record::Timings;
use crate::pipeline::progress::Progress;
use crate::pipeline::{render_views, Fitted};
use crate::reshade::net::choice::Head;
use crate::reshade::net::NetReshader;
use crate::reshade::TrainingFrame;
use crate::views::{robust_focus, robust_range, ViewCamera, ViewRig};

use super::report::{Case, StageRow, Stat};
use super::{io_err, stage_stats, BenchError, BenchReshader, Context};

/// Writes the deterministic synthetic photo (the reshading benchmark's test scene) as a
/// JPEG, so that decoding it is part of the measurement like for a real photo.
pub fn write_synthetic_photo(dir: &Path, (w, h): (u32, u32)) -> Result<PathBuf, BenchError> {
    let (image, _) = crate::eval::reshade::test_scene(w, h);
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
    let mut candidate = Vec::with_capacity(runs);
    for _ in 0..runs {
        let run = run_once(ctx, photo, board)?;
        candidate.extend(run.candidate_ms);
        all.push(run.times);
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
        work_size: first.work_size,
        stages,
        total,
        peak_rss_mib: None,
        candidate_reshading: Stat::of(&candidate),
    })
}

struct Run {
    times: RunTimes,
    /// Reshading with the candidate options, outside `times`.
    candidate_ms: Option<f64>,
    photo_size: [u32; 2],
    depth_input: (usize, usize),
    work_size: [u32; 2],
}

/// The photo's colours and depth at view size, with the board's cameras, as `render`
/// prepares them.
struct Prepared {
    fitted: Fitted,
    cameras: Vec<ViewCamera>,
    frame: TrainingFrame,
}

fn run_once(ctx: &Context, photo: &Path, board: &Board) -> Result<Run, BenchError> {
    let mut t = RunTimes::new();
    let (photo, rgb) = timed(&mut t, "decode", || -> Result<_, BenchError> {
        let photo = Photo::load(photo, None)?;
        let rgb = photo.image.to_rgb8();
        Ok((photo, rgb))
    })?;
    let depth_input = ctx.depth.network_size(rgb.width(), rgb.height())?;
    let estimate = timed(&mut t, "depth", || ctx.depth.estimate(&rgb))?;
    let (vw, vh) = board.view_size();
    // As in `render`: the depth comes at the size the photo is fitted to for the views.
    let (dw, dh) = Fitted::size((rgb.width(), rgb.height()), (vw, vh));
    let (depth, _) = timed(&mut t, "depth refinement", || {
        scene_depth(
            &ctx.depth,
            &estimate,
            &rgb,
            [dw as usize, dh as usize],
            &StageOptions::default(),
            Instant::now(),
        )
    });
    let fitted = timed(&mut t, "fit to view size", || {
        Fitted::new(&photo.image, photo.hfov_deg, &depth, vw, vh)
    });
    let photo_size = [rgb.width(), rgb.height()];
    // As in `render`: nothing at the photo's full resolution is held past the fit.
    drop((photo, rgb, estimate, depth));
    let prepared = cameras(fitted, board)?;
    let views = reshade_and_relocate(ctx, &prepared, &mut t)?;
    let candidate_ms = ctx
        .candidate
        .as_ref()
        .map(|net| time_reshading(net, &prepared))
        .transpose()?;
    let weaver = timed(&mut t, "weave table", || {
        Weaver::new(board, vw, vh).with_threads(ctx.threads)
    });
    let panel = timed(&mut t, "weave", || weaver.weave(&views))?;
    let out = ctx.work_dir.0.join("panel.png");
    timed(&mut t, "encode/write", || -> Result<(), BenchError> {
        let bytes = crate::io::output::encode_png(&out, &panel)?;
        crate::io::output::write_atomic(&out, &bytes)?;
        Ok(())
    })?;
    Ok(Run {
        times: t,
        candidate_ms,
        photo_size,
        depth_input,
        work_size: [
            prepared.fitted.image.width(),
            prepared.fitted.image.height(),
        ],
    })
}

/// The board's cameras with the focus and parallax budget `render` picks by default.
fn cameras(fitted: Fitted, board: &Board) -> Result<Prepared, BenchError> {
    let focus = robust_focus(&fitted.depth);
    let cone = f64::from(board.view_cone_deg());
    let depthiness =
        ViewRig::fitting_depthiness(cone, focus, robust_range(&fitted.depth), &fitted.reference);
    let rig = ViewRig::new(board.views(), cone, focus, depthiness)?;
    Ok(Prepared {
        cameras: rig.cameras(&fitted.reference),
        frame: TrainingFrame::for_focus(focus),
        fitted,
    })
}

/// Every view reshaded and relocated as `render` does it ([`render_views`]: the views
/// stream from the reshading into the relocation, one per core at a time), with the
/// per-photo halves (reshading encoder, relocation build) and the per-view ones timed
/// apart.
fn reshade_and_relocate(
    ctx: &Context,
    p: &Prepared,
    t: &mut RunTimes,
) -> Result<Vec<RgbImage>, BenchError> {
    let mut times = Timings::default();
    let shading: Vec<[f64; 3]> = p.cameras.iter().map(|c| c.centre).collect();
    let views = render_views(
        &p.fitted,
        (&p.cameras, &shading),
        p.frame,
        Some(ctx.reshader.as_reshader()),
        &*ctx.relocator,
        &Progress::hidden(),
        &mut times,
    )?;
    t.extend([
        ("LDI build + inpainting", times.ms("relocate_prepare")),
        ("reshade encoder", times.ms("reshade_prepare")),
        ("reshade decoder × views", times.ms("reshade")),
        ("LDI render × views", times.ms("relocate")),
    ]);
    Ok(views)
}

/// Encoder and decoder × views of `net` for the prepared photo, in ms.
fn time_reshading(net: &NetReshader, p: &Prepared) -> Result<f64, BenchError> {
    let started = Instant::now();
    let depth = p.frame.depth(&p.fitted.depth);
    let photo = net.prepare_photo(&p.fitted.image, &depth)?;
    let centres: Vec<[f64; 3]> = p.cameras.iter().map(|c| p.frame.camera(c.centre)).collect();
    photo.reshade_views(&centres)?;
    Ok(started.elapsed().as_secs_f64() * 1e3)
}

/// The size the network runs at, and the residual's (or the lobe head's change's)
/// upsampling when it is reduced.
fn reshade_size(ctx: &Context, ww: u32, wh: u32) -> String {
    let (nw, nh) = ctx
        .reshader
        .options()
        .working_size(ww as usize, wh as usize);
    if (nw, nh) != (ww as usize, wh as usize) {
        let what = match ctx.reshader.head() {
            Head::Residual => "residual",
            Head::Lobes => "change",
        };
        format!("{nw}x{nh} for {ww}x{wh} ({what} upsampled)")
    } else {
        format!("{ww}x{wh}")
    }
}

fn detail(ctx: &Context, stage: &str, board: &Board, run: &Run) -> String {
    let views = board.views();
    let [ww, wh] = run.work_size;
    match stage {
        "decode" => {
            "Photo::load: decode to 8-bit RGB, EXIF orientation and field of view, float sRGB"
                .into()
        }
        "depth" => format!(
            "{} {} ({}), network input {}x{}",
            ctx.depth.manifest().name,
            ctx.depth.manifest().version,
            ctx.depth.manifest().precision,
            run.depth_input.0,
            run.depth_input.1
        ),
        "depth refinement" => {
            "upsample to the working size, edge-aware refinement, scene scaling".into()
        }
        "fit to view size" => {
            format!("photo resized to {ww}x{wh} (the depth is already at that size)")
        }
        "LDI build + inpainting" => format!(
            "once per photo at {ww}x{wh} by the runtime's relocator: {}",
            ctx.relocator.description()
        ),
        "reshade encoder" if ctx.reshader.head() == Head::Lobes => format!(
            "lobe network once per photo at {}",
            reshade_size(ctx, ww, wh)
        ),
        "reshade decoder × views" if ctx.reshader.head() == Head::Lobes => {
            let threads = match &ctx.reshader {
                BenchReshader::Lobes(net) => net.threads(),
                BenchReshader::Residual(_) => 0,
            };
            format!(
                "{views} views, the lobe head's closed form per view in Rust on {threads} threads (no network), at {}",
                reshade_size(ctx, ww, wh)
            )
        }
        "reshade encoder" if matches!(&ctx.reshader, BenchReshader::Residual(net) if net.is_split()) =>
        {
            format!("once per photo at {}", reshade_size(ctx, ww, wh))
        }
        "reshade encoder" => {
            "single-graph model: only input preparation here, the whole network runs per view"
                .into()
        }
        "reshade decoder × views" => {
            let o = ctx.reshader.options();
            let network = match o.key_views {
                Some(k) if k < views => {
                    format!("network on {k} key views, the others interpolated")
                }
                _ => "network on every view".into(),
            };
            format!("{views} views, {network}, at {}", reshade_size(ctx, ww, wh))
        }
        "LDI render × views" => {
            let (vw, vh) = board.view_size();
            format!(
                "{views} views of {vw}x{vh}, rounded to 8-bit, one per core ({} threads)",
                crate::parallel::cores()
            )
        }
        "weave table" => {
            "Weaver::new: subpixel→view table for the board (once per board and view size)".into()
        }
        "weave" => format!("subpixel weave of the 8-bit views, {} threads", ctx.threads),
        "encode/write" => "panel PNG encode + atomic write".into(),
        _ => String::new(),
    }
}
