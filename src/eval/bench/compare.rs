//! The comparisons beside the runtime's own times: tract against onnxruntime on the same
//! ONNX files, and the naive configuration (the paper-size network run per view).

use std::path::Path;

use interleave::Board;

use crate::engine::manifest::{self, Precision};
use crate::reshade::net::choice::Head;

use super::models::{cached_export, python, reshade_manifests, script};
use super::peer::{self, Job};
use super::report::{Case, NaiveRow, PeerRow, Stat};
use super::{BenchConfig, BenchError, Context};

pub(super) fn padded(v: u32, multiple: usize) -> usize {
    (v as usize).div_ceil(multiple.max(1)) * multiple.max(1)
}

/// tract and onnxruntime on the depth models (at the network size the synthetic photo
/// gets) and on every precision of the reshading model's files (at the size the first
/// board's last case reshaded at).
pub(super) fn peer_rows(
    args: &BenchConfig,
    ctx: &Context,
    model: &Path,
    head: Head,
    cases: &[Case],
) -> Result<Vec<PeerRow>, BenchError> {
    let mut jobs = Vec::new();
    let (dw, dh) = ctx.depth.network_size(args.synthetic.0, args.synthetic.1)?;
    for precision in [Precision::Int8, Precision::Fp32] {
        let path = crate::depth::net::shipped_manifest(precision)?;
        let model = manifest::load_verified(&path)?;
        jobs.push(Job::for_manifest(
            &format!("depth {}", model.manifest.name),
            &model,
            dh,
            dw,
        )?);
    }
    if let Some(case) = cases
        .iter()
        .rev()
        .find(|c| Some(&c.board) == cases.first().map(|f| &f.board))
    {
        let [ww, wh] = case.work_size;
        for path in reshade_manifests(model, None, head)? {
            let model = manifest::load_verified(&path)?;
            let m = model.manifest.size_multiple as usize;
            let label = format!("{} {}", model.manifest.task, model.manifest.name);
            jobs.push(Job::for_manifest(
                &label,
                &model,
                padded(wh, m),
                padded(ww, m),
            )?);
        }
    }
    let (version, ort) = match python(args).and_then(|py| {
        peer::time_onnxruntime(
            &py,
            &script("peer_onnxruntime.py"),
            &jobs,
            args.threads,
            args.runs.max(3),
        )
    }) {
        Ok((v, r)) => (Some(v), r),
        Err(e) => {
            log::warn!("onnxruntime peer not run: {e}");
            (None, Vec::new())
        }
    };
    Ok(jobs
        .iter()
        .map(|job| peer_row(args, job, &ort, version.as_deref()))
        .collect())
}

fn peer_row(
    args: &BenchConfig,
    job: &Job,
    ort: &[(String, Result<Stat, String>)],
    version: Option<&str>,
) -> PeerRow {
    let tract = peer::time_tract(job, args.threads, args.runs.max(3));
    let ort_time = ort
        .iter()
        .find(|(l, _)| *l == job.label)
        .map(|(_, r)| r.clone());
    let mut notes = Vec::new();
    if let Err(e) = &tract {
        notes.push(format!("tract: {e}"));
    }
    match (&ort_time, version) {
        (Some(Err(e)), _) => notes.push(format!("onnxruntime: {e}")),
        (None, _) => notes.push("onnxruntime not run (see log)".into()),
        (Some(Ok(_)), Some(v)) => notes.push(format!("onnxruntime {v}")),
        (Some(Ok(_)), None) => {}
    }
    PeerRow {
        model: job.label.clone(),
        shapes: job.shapes_text(),
        tract: tract.ok(),
        onnxruntime: ort_time.and_then(Result::ok),
        note: Some(notes.join("; ")),
    }
}

pub(super) fn naive_rows(
    args: &BenchConfig,
    boards: &[Board],
    cases: &[Case],
) -> Result<Vec<NaiveRow>, BenchError> {
    let model = match cached_export(args, "full", false, Precision::Fp32) {
        Ok(path) => manifest::load_verified(&path)?,
        Err(e) => {
            log::warn!("naive configuration not run: {e}");
            return Ok(boards
                .iter()
                .map(|b| NaiveRow {
                    board: b.name().into(),
                    views: b.views(),
                    network_size: [0, 0],
                    per_view: None,
                    timed_views: 0,
                    runtime_ms: None,
                    candidate_ms: None,
                    note: Some(format!("not run: {e}")),
                })
                .collect());
        }
    };
    let m = model.manifest.size_multiple as usize;
    let mut rows = Vec::new();
    for board in boards {
        let Some(runtime) = runtime_reshading(cases, board.name()) else {
            continue;
        };
        let [ww, wh] = runtime.work_size;
        let (pw, ph) = (padded(ww, m), padded(wh, m));
        let job = Job::for_manifest("naive", &model, ph, pw)?;
        let per_view = peer::time_tract(&job, args.threads, args.naive_views);
        rows.push(NaiveRow {
            board: board.name().into(),
            views: board.views(),
            network_size: [pw, ph],
            per_view: per_view.as_ref().ok().copied(),
            timed_views: args.naive_views,
            runtime_ms: Some(runtime.ms),
            candidate_ms: runtime.candidate_ms,
            note: Some(match per_view {
                Err(e) => format!("failed: {e}"),
                Ok(_) => format!("runtime figure from {}", runtime.photo),
            }),
        });
    }
    Ok(rows)
}

/// The runtime's reshading stage for one board.
struct RuntimeReshading {
    ms: f64,
    candidate_ms: Option<f64>,
    photo: String,
    work_size: [u32; 2],
}

/// Encoder + decoder × views medians for `board`, preferring the synthetic photo's case
/// (the largest), with the photo it came from and the size it reshaded at.
fn runtime_reshading(cases: &[Case], board: &str) -> Option<RuntimeReshading> {
    cases
        .iter()
        .rev()
        .filter(|c| c.board == board)
        .find_map(|c| {
            let enc = c.stage("reshade encoder")?.time?;
            let dec = c.stage("reshade decoder × views")?.time?;
            Some(RuntimeReshading {
                ms: enc.median_ms + dec.median_ms,
                candidate_ms: c.candidate_reshading.map(|s| s.median_ms),
                photo: c.photo.clone(),
                work_size: c.work_size,
            })
        })
}
