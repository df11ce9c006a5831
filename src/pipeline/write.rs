//! Writing a render's products: the woven frame, quilt, side-by-side pair and views, the
//! previews and the RGB-D image, staged and committed together with run.json.

use std::path::Path;

use image::RgbImage;
use interleave::{make_quilt, side_by_side, Board, WeaveError, Weaver};

use super::record::{BoardRecord, RgbdRecord, RunRecord, ViewRecord};
use crate::io::output::{self, Staging};
use crate::io::preview;
use crate::io::record::{FileRecord, Timings};
use crate::views::{Intrinsics, ViewCamera};

use super::{Fitted, PipelineError, Product, RenderOptions};

pub(super) fn write_products(
    opts: &RenderOptions,
    views: &[RgbImage],
    (left, right): (usize, usize),
    staging: &mut Staging,
    t: &mut Timings,
) -> Result<(), PipelineError> {
    let board = &opts.board;
    // The quilt carries its layout in its metadata, so it is encoded apart.
    if opts.wants(Product::Quilt) {
        let (cols, rows) = board.quilt_grid();
        let quilt = t.time("quilt", || make_quilt(views, cols, rows))?;
        let layout = interleave::QuiltLayout::of(board);
        let name = layout.file_name();
        let bytes = t.time("encode", || {
            crate::io::quilt_file::encode(&staging.final_path(&name), &quilt, &layout)
        })?;
        t.time("write", || staging.write(&name, &bytes))?;
    }
    if opts.wants(Product::Views) {
        let names: Vec<String> = (0..views.len())
            .map(|i| format!("views/{}", output::view_file_name(i)))
            .collect();
        let jobs: Vec<_> = names
            .iter()
            .zip(views)
            .map(|(name, view)| (staging.final_path(name), view))
            .collect();
        let encoded = t.time("encode", || output::encode_pngs(&jobs))?;
        for (name, bytes) in names.iter().zip(&encoded) {
            t.time("write", || staging.write(name, bytes))?;
        }
    }
    let mut stage_png = |rel: &str, image: &RgbImage, t: &mut Timings| {
        let bytes = t.time("encode", || {
            output::encode_png(&staging.final_path(rel), image)
        })?;
        t.time("write", || staging.write(rel, &bytes))
    };
    if opts.wants(Product::Panel) {
        let panel = weave(board, views, t)?;
        stage_png("panel.png", &panel, t)?;
    }
    if opts.wants(Product::Sbs) {
        let sbs = side_by_side(&views[left], &views[right]);
        stage_png("sbs.png", &sbs, t)?;
    }
    write_previews(opts, views, staging, t)
}

/// Stages `preview.gif` and `preview.html`, both from the views shrunk once.
fn write_previews(
    opts: &RenderOptions,
    views: &[RgbImage],
    staging: &mut Staging,
    t: &mut Timings,
) -> Result<(), PipelineError> {
    const GIF: &str = "preview.gif";
    const HTML: &str = "preview.html";
    let (gif, html) = (opts.wants(Product::Preview), opts.wants(Product::Html));
    if !(gif || html) {
        return Ok(());
    }
    let frames = t.time("preview_shrink", || preview::shrink(views));
    if gif {
        let bytes = t.time("preview_gif", || {
            preview::animation::encode(&staging.final_path(GIF), &frames)
        })?;
        t.time("write", || staging.write(GIF, &bytes))?;
    }
    if html {
        let title = opts.photo.file_name().unwrap_or_default().to_string_lossy();
        let page = t.time("preview_html", || {
            preview::page::render(&staging.final_path(HTML), &title, &frames)
        })?;
        t.time("write", || staging.write(HTML, page.as_bytes()))?;
    }
    Ok(())
}

/// Stages `rgbd.png`: the fitted photo beside its depth, with the focus and depthiness of
/// the views in its text chunks, so that an RGB-D viewer can show what the panel shows.
pub(super) fn write_rgbd(
    fitted: &Fitted,
    focus: f64,
    depthiness: f64,
    staging: &mut Staging,
    t: &mut Timings,
) -> Result<RgbdRecord, PipelineError> {
    const FILE: &str = "rgbd.png";
    let (image, span) = t.time("rgbd", || {
        super::rgbd::compose(&fitted.image, &fitted.depth)
    });
    let text = [
        (
            "Software",
            format!("reshader {}", env!("CARGO_PKG_VERSION")),
        ),
        ("Description", "RGB-D: colour left, depth right".to_string()),
        ("Focus", focus.to_string()),
        ("Depthiness", depthiness.to_string()),
        ("Depth near", span.near.to_string()),
        ("Depth far", span.far.to_string()),
        ("Depth encoding", super::rgbd::ENCODING.to_string()),
    ];
    let bytes = t.time("encode", || {
        output::encode_png_with_text(&staging.final_path(FILE), &image, &text)
    })?;
    t.time("write", || staging.write(FILE, &bytes))?;
    Ok(RgbdRecord {
        file: FILE.into(),
        size: [fitted.image.width(), fitted.image.height()],
        focus,
        depthiness,
        depth_near: span.near,
        depth_far: span.far,
        depth_encoding: super::rgbd::ENCODING,
    })
}

pub(super) fn weave(
    board: &Board,
    views: &[RgbImage],
    t: &mut Timings,
) -> Result<RgbImage, PipelineError> {
    let (w, h) = views
        .first()
        .map(RgbImage::dimensions)
        .ok_or(WeaveError::ViewCount {
            expected: board.views(),
            got: 0,
        })?;
    let weaver = t.time("weave_table", || Weaver::new(board, w, h));
    Ok(t.time("weave", || weaver.weave(views))?)
}

pub(super) fn commit_with_record(
    mut staging: Staging,
    mut record: RunRecord,
) -> Result<RunRecord, PipelineError> {
    record.outputs = staging_outputs(&staging);
    record.outputs.push("run.json".into());
    let json = serde_json::to_vec_pretty(&record).expect("run record serialises");
    staging.write("run.json", &json)?;
    staging.commit()?;
    Ok(record)
}

fn staging_outputs(staging: &Staging) -> Vec<String> {
    staging
        .files()
        .iter()
        .map(|p| p.display().to_string())
        .collect()
}

pub(super) fn file_record(path: Option<&Path>) -> Result<Option<FileRecord>, PipelineError> {
    path.map(|p| {
        FileRecord::of(p).map_err(|source| PipelineError::Io {
            path: p.into(),
            source,
        })
    })
    .transpose()
}

pub(super) fn board_record(board: &Board) -> BoardRecord {
    let (pw, ph) = board.panel_size();
    let (qc, qr) = board.quilt_grid();
    let (vw, vh) = board.view_size();
    BoardRecord {
        name: board.name().into(),
        origin: board.origin().into(),
        panel_size: [pw, ph],
        views: board.views(),
        quilt_grid: [qc, qr],
        view_size: [vw, vh],
        view_cone_deg: board.view_cone_deg(),
    }
}

pub(super) fn view_records(
    cameras: &[ViewCamera],
    shading: &[[f64; 3]],
    reference: &Intrinsics,
) -> Vec<ViewRecord> {
    cameras
        .iter()
        .zip(shading)
        .enumerate()
        .map(|(index, (cam, &shading_camera))| ViewRecord {
            index,
            camera: cam.centre,
            shading_camera,
            principal_shift_px: [
                cam.intrinsics.cx - reference.cx,
                cam.intrinsics.cy - reference.cy,
            ],
        })
        .collect()
}
