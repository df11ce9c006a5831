//! The reshading benchmark: per-view cost of each precision and engine, the encoder's
//! cost, achieved GFLOP/s, and the per-view cost options (a) reduced working resolution,
//! (b) key views, (c) batching, plus parallel views, each with its fidelity (PSNR)
//! against plain per-view full-resolution reshading. Where the model directory (or
//! `--lobes-model`) has a lobe-head model, its rows ("`<precision>` lobes") give the network's
//! once-per-photo cost and the closed form's cost per view. Run by
//! `cargo bench --bench reshade` (arguments after `--`) and printed as Markdown tables.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use crate::depth::DepthMap;
use crate::engine::manifest::Precision;
use crate::engine::{self, Engine};
use crate::io::photo::SrgbImage;
use crate::reshade::net::lobes::LobeReshader;
use crate::reshade::net::{NetOptions, NetReshader};
use crate::views::{Intrinsics, ViewRig};

/// Why the reshading benchmark could not run (a row that fails is reported in its table).
#[derive(Debug, thiserror::Error)]
pub enum ReshadeBenchError {
    #[error("reshading model: {0}")]
    Net(#[from] crate::reshade::net::NetError),
    #[error(transparent)]
    Engine(#[from] crate::engine::EngineError),
    #[error(transparent)]
    Reshade(#[from] crate::reshade::ReshadeError),
    #[error(transparent)]
    View(#[from] crate::views::ViewError),
}

/// Horizontal field of view of the test scene's camera (the lobe head needs its rays).
pub const TEST_SCENE_HFOV_DEG: f64 = 60.0;

#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub model: PathBuf,
    pub width: u32,
    pub height: u32,
    pub views: usize,
    pub cone_deg: f64,
    pub threads: usize,
    pub engines: Vec<String>,
    pub precisions: Vec<Precision>,
    /// Views timed per precision/engine row (the options table uses `views`).
    pub timed_views: usize,
    /// The lobe-head model timed in the "lobes" rows (None: `model`, when it holds one).
    pub lobes_model: Option<PathBuf>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            model: PathBuf::from("models/reshade"),
            width: 640,
            height: 384,
            views: 48,
            cone_deg: 40.0,
            threads: 2,
            engines: engine::ENGINES.iter().map(|s| s.to_string()).collect(),
            precisions: vec![Precision::Fp32, Precision::Fp16, Precision::Int8],
            timed_views: 8,
            lobes_model: None,
        }
    }
}

/// A deterministic test photo with smooth shading, edges and a few bright spots, and a
/// depth map of a tilted ground plane with two nearer discs (depths 1–5, training units).
pub fn test_scene(width: u32, height: u32) -> (SrgbImage, DepthMap) {
    let (w, h) = (width as usize, height as usize);
    let mut img = SrgbImage::new(width, height);
    let mut depth = vec![0.0f32; w * h];
    let discs = [(0.3, 0.55, 0.18, 1.2f32), (0.7, 0.45, 0.12, 1.8)];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f64 / w as f64, y as f64 / h as f64);
            let mut z = 5.0 - 3.0 * v as f32;
            let mut rgb = [0.35 + 0.3 * u, 0.4 + 0.2 * v, 0.5 - 0.2 * u];
            for &(cx, cy, r, dz) in &discs {
                let d2 = ((u - cx) * w as f64 / h as f64).powi(2) + (v - cy).powi(2);
                if d2 < r * r {
                    z = dz;
                    let shade = 1.0 - d2 / (r * r);
                    let spot = (-(d2 / (0.02 * r * r))).exp();
                    rgb = [0.6 * shade + spot, 0.3 * shade + spot, 0.2 * shade + spot];
                }
            }
            depth[y * w + x] = z;
            img.put(x as u32, y as u32, rgb.map(|c| c.clamp(0.0, 1.0) as f32));
        }
    }
    (img, DepthMap::new(w, h, depth))
}

/// Convolution GFLOP (2 × multiply-adds) of the encoder and of one decoder run for the
/// manifest's architecture at `h`×`w`, counted as the training toolchain counts them.
/// `out` is the last convolution's channel count: 3 for the paper's residual head, 9 for
/// the camera-linear head (a 3×3 Jacobian per pixel).
pub fn conv_gflop(
    widths: &[u64],
    convs: &[u64],
    out: u64,
    h: usize,
    w: usize,
) -> Option<(f64, f64)> {
    if widths.len() != 6 || convs.len() != 6 {
        return None;
    }
    let px = |level: usize| (h >> level) as f64 * (w >> level) as f64;
    let conv = |level: usize, cin: u64, cout: u64| 2.0 * px(level) * (cin * cout * 9) as f64;
    let mut enc = 0.0;
    let mut cin = 3 + 11;
    for level in 0..6 {
        for i in 0..convs[level] {
            enc += conv(
                level,
                if i == 0 { cin } else { widths[level] },
                widths[level],
            );
        }
        cin = widths[level];
    }
    let mut dec = 0.0;
    for i in 0..convs[5] {
        let c = if i == 0 { widths[5] + 128 } else { widths[5] };
        dec += conv(5, c, widths[5]);
    }
    for level in (0..5).rev() {
        for i in 0..convs[level] {
            let c = if i == 0 {
                widths[level + 1] + widths[level]
            } else {
                widths[level]
            };
            dec += conv(level, c, widths[level]);
        }
    }
    dec += conv(0, widths[0], out);
    Some((enc / 1e9, dec / 1e9))
}

/// Widths, convolutions per level and the last convolution's output channels (absent in
/// manifests from before the camera-linear head: 3).
fn architecture(model: &Path, precision: Precision) -> Option<(Vec<u64>, Vec<u64>, u64)> {
    let dir = if model.is_dir() {
        model
    } else {
        model.parent()?
    };
    for entry in std::fs::read_dir(dir).ok()?.flatten() {
        let Ok(m) = crate::engine::manifest::Manifest::load(&entry.path()) else {
            continue;
        };
        if m.precision != precision {
            continue;
        }
        let arch = m.architecture?;
        let list = |k: &str| -> Option<Vec<u64>> {
            arch.get(k)?
                .as_array()?
                .iter()
                .map(|v| v.as_u64())
                .collect()
        };
        let out = arch.get("out_channels").map_or(Some(3), |v| v.as_u64())?;
        return Some((list("widths")?, list("convs")?, out));
    }
    None
}

fn psnr(a: &SrgbImage, b: &SrgbImage) -> f64 {
    let mse = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| f64::from(x - y).powi(2))
        .sum::<f64>()
        / a.data().len() as f64;
    super::stats::psnr_from_mse(mse)
}

/// Mean PSNR over views (identical views count as 99 dB so that the mean stays finite).
fn mean_psnr(a: &[SrgbImage], b: &[SrgbImage]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| psnr(x, y).min(99.0))
        .sum::<f64>()
        / a.len() as f64
}

struct Timed {
    encoder_ms: f64,
    per_view_ms: f64,
    views: Vec<SrgbImage>,
}

fn time_views(
    net: &NetReshader,
    image: &SrgbImage,
    depth: &DepthMap,
    centres: &[[f64; 3]],
) -> Result<Timed, ReshadeBenchError> {
    // Warm-up: plans are built (and cached) outside the timed region.
    let warm = net.prepare_photo(image, depth)?;
    warm.reshade_views(&centres[..centres.len().min(net.options().batch.max(1) * 2)])?;
    drop(warm);
    let started = Instant::now();
    let prepared = net.prepare_photo(image, depth)?;
    let encoder_ms = started.elapsed().as_secs_f64() * 1e3;
    let started = Instant::now();
    let views = prepared.reshade_views(centres)?;
    let per_view_ms = started.elapsed().as_secs_f64() * 1e3 / centres.len() as f64;
    Ok(Timed {
        encoder_ms,
        per_view_ms,
        views,
    })
}

fn load(
    config: &BenchConfig,
    engine: &Arc<dyn Engine>,
    precision: Precision,
    options: NetOptions,
) -> Result<NetReshader, ReshadeBenchError> {
    Ok(NetReshader::load(
        &config.model,
        precision,
        engine.clone(),
        options,
    )?)
}

/// The lobe-head model to time: `--lobes-model`, else `--model` when it is a lobe-head
/// manifest or a directory holding one (None: no lobes rows).
fn lobes_model(config: &BenchConfig) -> Option<PathBuf> {
    if let Some(p) = &config.lobes_model {
        return Some(p.clone());
    }
    let m = &config.model;
    let has = if m.is_dir() {
        crate::reshade::net::lobes::heads_in(m).is_ok_and(|(lobes, _)| lobes)
    } else {
        is_lobes_manifest(m)
    };
    has.then(|| m.clone())
}

fn is_lobes_manifest(path: &Path) -> bool {
    path.is_file()
        && crate::engine::manifest::Manifest::load(path)
            .is_ok_and(|m| m.task == crate::engine::manifest::Task::ReshadeLobes)
}

/// The lobe network once for the photo, then the closed form for every camera, timed
/// after one untimed warm-up (plan building).
fn time_lobe_views(
    net: &LobeReshader,
    image: &SrgbImage,
    depth: &DepthMap,
    centres: &[[f64; 3]],
) -> Result<Timed, ReshadeBenchError> {
    let camera = Intrinsics::from_hfov(image.width(), image.height(), TEST_SCENE_HFOV_DEG);
    let warm = net.prepare_photo(image, depth, &camera)?;
    warm.reshade_view(centres[0])?;
    drop(warm);
    let started = Instant::now();
    let prepared = net.prepare_photo(image, depth, &camera)?;
    let encoder_ms = started.elapsed().as_secs_f64() * 1e3;
    let started = Instant::now();
    let views = centres
        .iter()
        .map(|&c| prepared.reshade_view(c))
        .collect::<Result<Vec<_>, _>>()?;
    let per_view_ms = started.elapsed().as_secs_f64() * 1e3 / centres.len() as f64;
    Ok(Timed {
        encoder_ms,
        per_view_ms,
        views,
    })
}

/// Runs the benchmark and returns its report as Markdown.
pub fn run(config: &BenchConfig) -> Result<String, ReshadeBenchError> {
    let (image, depth) = test_scene(config.width, config.height);
    let rig = ViewRig::new(config.views, config.cone_deg, 2.0, 1.0)?;
    let centres: Vec<[f64; 3]> = rig.offsets().into_iter().map(|x| [x, 0.0, 0.0]).collect();
    let timed = &centres[..config.timed_views.min(centres.len())];
    let mut out = String::new();
    let _ = writeln!(
        out,
        "## Reshading benchmark\n\nmodel {}, {}x{}, {} threads, {} views over a {}° cone at focus 2\n",
        config.model.display(),
        config.width,
        config.height,
        config.threads,
        config.views,
        config.cone_deg
    );
    precision_table(config, &image, &depth, timed, &mut out)?;
    if is_lobes_manifest(&config.model) {
        // A lobe-head model alone: no residual network to profile or to vary per view.
        return Ok(out);
    }
    profile_table(config, &image, &depth, &mut out)?;
    options_table(config, &image, &depth, &centres, &mut out)?;
    Ok(out)
}

fn precision_table(
    config: &BenchConfig,
    image: &SrgbImage,
    depth: &DepthMap,
    centres: &[[f64; 3]],
    out: &mut String,
) -> Result<(), ReshadeBenchError> {
    let _ = writeln!(
        out,
        "| engine | precision | encoder ms | decoder ms/view | decoder GFLOP/s | ms/view vs ort |\n|---|---|---|---|---|---|"
    );
    let mut ort_ms: Vec<(Precision, f64)> = Vec::new();
    let mut rows = Vec::new();
    let residual = !is_lobes_manifest(&config.model);
    for name in config.engines.iter().filter(|_| residual) {
        let engine = engine::by_name(name, config.threads)?;
        for &precision in &config.precisions {
            let net = match load(config, &engine, precision, at_full_size()) {
                Ok(net) => net,
                Err(e) => {
                    rows.push(format!("| {name} | {precision} | failed: {e} | | | |"));
                    continue;
                }
            };
            let t = match time_views(&net, image, depth, centres) {
                Ok(t) => t,
                Err(e) => {
                    rows.push(format!("| {name} | {precision} | failed: {e} | | | |"));
                    continue;
                }
            };
            if name == "ort" {
                ort_ms.push((precision, t.per_view_ms));
            }
            let gflops = architecture(&config.model, precision)
                .and_then(|(w, c, out)| {
                    conv_gflop(&w, &c, out, config.height as usize, config.width as usize)
                })
                .map_or("?".into(), |(_, dec)| {
                    format!("{:.1}", dec / (t.per_view_ms / 1e3))
                });
            rows.push(format!(
                "| {name} | {precision} | {:.1} | {:.1} | {gflops} | {{ort:{precision}:{}}} |",
                t.encoder_ms, t.per_view_ms, t.per_view_ms
            ));
        }
    }
    let lobes = lobes_model(config);
    if let Some(model) = &lobes {
        lobe_rows(config, model, image, depth, centres, &mut rows)?;
    }
    for row in rows {
        let _ = writeln!(out, "{}", fill_ratio(&row, &ort_ms));
    }
    if let Some(model) = lobes {
        let _ = writeln!(
            out,
            "\n\"lobes\" rows: {}, the lobe head: \"encoder ms\" is its network, run once per photo; \"decoder ms/view\" the closed form per view in Rust on {} threads (no network call; the view's change added to the photo and clamped).",
            model.display(),
            config.threads
        );
    }
    Ok(())
}

/// One row per engine and precision of the lobe-head model at `model` (precisions it was
/// not exported at are left out).
fn lobe_rows(
    config: &BenchConfig,
    model: &Path,
    image: &SrgbImage,
    depth: &DepthMap,
    centres: &[[f64; 3]],
    rows: &mut Vec<String>,
) -> Result<(), ReshadeBenchError> {
    for name in &config.engines {
        let engine = engine::by_name(name, config.threads)?;
        for &precision in &config.precisions {
            let has_precision = !model.is_dir()
                || crate::reshade::net::manifests_where(model, Some(precision), |t| {
                    t == crate::engine::manifest::Task::ReshadeLobes
                })
                .is_ok_and(|m| !m.is_empty());
            if !has_precision {
                continue;
            }
            let timed = LobeReshader::load(model, precision, engine.clone(), at_full_size())
                .map_err(ReshadeBenchError::from)
                .and_then(|net| time_lobe_views(&net, image, depth, centres));
            rows.push(match timed {
                Ok(t) => format!(
                    "| {name} | {precision} lobes | {:.1} | {:.2} | – | – |",
                    t.encoder_ms, t.per_view_ms
                ),
                Err(e) => format!("| {name} | {precision} lobes | failed: {e} | | | |"),
            });
        }
    }
    Ok(())
}

/// Replaces the `{ort:precision:ms}` placeholder with the ratio to onnxruntime's time.
fn fill_ratio(row: &str, ort_ms: &[(Precision, f64)]) -> String {
    let Some(start) = row.find("{ort:") else {
        return row.to_owned();
    };
    let end = start + row[start..].find('}').expect("placeholder closes");
    let mut parts = row[start + 5..end].split(':');
    let precision: Option<Precision> = parts.next().and_then(|p| p.parse().ok());
    let ms: f64 = parts
        .next()
        .and_then(|m| m.parse().ok())
        .unwrap_or(f64::NAN);
    let ratio = ort_ms
        .iter()
        .find(|(p, _)| Some(*p) == precision)
        .map_or("–".into(), |(_, o)| format!("{:.2}×", ms / o));
    format!("{}{ratio}{}", &row[..start], &row[end + 1..])
}

/// Where tract spends a decoder run, by operator type.
fn profile_table(
    config: &BenchConfig,
    image: &SrgbImage,
    depth: &DepthMap,
    out: &mut String,
) -> Result<(), ReshadeBenchError> {
    let precision = config.precisions[0];
    let tract = engine::tract::TractEngine::new(config.threads);
    let engine: Arc<dyn Engine> = Arc::new(engine::tract::TractEngine::new(config.threads));
    let net = load(config, &engine, precision, at_full_size())?;
    let prepared = net.prepare_photo(image, depth)?;
    let ops = prepared.profile(&tract, [0.2, 0.0, 0.0])?;
    let total: f64 = ops.iter().map(|(_, ms)| ms).sum();
    let _ = writeln!(
        out,
        "\n### tract decoder profile ({precision}, {} threads): {total:.1} ms\n\n| operator | ms | share |\n|---|---|---|",
        config.threads
    );
    for (op, ms) in ops.iter().take(10) {
        let _ = writeln!(out, "| {op} | {ms:.1} | {:.0}% |", 100.0 * ms / total);
    }
    Ok(())
}

fn options_table(
    config: &BenchConfig,
    image: &SrgbImage,
    depth: &DepthMap,
    centres: &[[f64; 3]],
    out: &mut String,
) -> Result<(), ReshadeBenchError> {
    let precision = config.precisions[0];
    let threaded: Arc<dyn Engine> = Arc::new(engine::tract::TractEngine::new(config.threads));
    let single: Arc<dyn Engine> = Arc::new(engine::tract::TractEngine::new(1));
    let base = NetOptions {
        key_views: None,
        ..at_full_size()
    };
    let variants: Vec<(&str, Arc<dyn Engine>, NetOptions)> = vec![
        (
            "plain: every view, full res, 2-thread kernels",
            threaded.clone(),
            base.clone(),
        ),
        (
            "parallel views: 2 views at once, 1-thread kernels",
            single.clone(),
            NetOptions {
                parallel_views: config.threads,
                ..base.clone()
            },
        ),
        (
            "(a) working resolution ×0.75",
            threaded.clone(),
            NetOptions {
                scale: 0.75,
                ..base.clone()
            },
        ),
        (
            "(a) working resolution ×0.5",
            threaded.clone(),
            NetOptions {
                scale: 0.5,
                ..base.clone()
            },
        ),
        (
            "(b) 16 key views",
            threaded.clone(),
            NetOptions {
                key_views: Some(16),
                ..base.clone()
            },
        ),
        (
            "(b) 8 key views",
            threaded.clone(),
            NetOptions {
                key_views: Some(8),
                ..base.clone()
            },
        ),
        (
            "(c) batch 2",
            threaded.clone(),
            NetOptions {
                batch: 2,
                ..base.clone()
            },
        ),
        (
            "(c) batch 4",
            threaded.clone(),
            NetOptions {
                batch: 4,
                ..base.clone()
            },
        ),
        (
            "(a)+(b) ×0.5 and 8 key views",
            threaded.clone(),
            NetOptions {
                scale: 0.5,
                key_views: Some(8),
                ..base.clone()
            },
        ),
        (
            "(a)+(b) ×0.5, 8 key views, parallel views",
            single,
            NetOptions {
                scale: 0.5,
                key_views: Some(8),
                parallel_views: config.threads,
                ..base
            },
        ),
    ];
    let _ = writeln!(
        out,
        "\n### Per-view cost options (tract, {precision}, {} views)\n\n| option | encoder ms | reshading ms/view | stage total ms | speed-up | PSNR vs plain (dB) |\n|---|---|---|---|---|---|",
        centres.len()
    );
    let mut plain: Option<(f64, Vec<SrgbImage>)> = None;
    for (label, engine, options) in variants {
        let row = load(config, &engine, precision, options)
            .and_then(|net| time_views(&net, image, depth, centres));
        let t = match row {
            Ok(t) => t,
            Err(e) => {
                let _ = writeln!(out, "| {label} | failed: {e} | | | | |");
                continue;
            }
        };
        let total = t.encoder_ms + t.per_view_ms * centres.len() as f64;
        let (speedup, fidelity) = match &plain {
            None => ("1.00×".to_owned(), "reference".to_owned()),
            Some((ms, views)) => (
                format!("{:.2}×", ms / total),
                format!("{:.2}", mean_psnr(&t.views, views)),
            ),
        };
        let _ = writeln!(
            out,
            "| {label} | {:.1} | {:.1} | {total:.0} | {speedup} | {fidelity} |",
            t.encoder_ms, t.per_view_ms
        );
        if plain.is_none() {
            plain = Some((total, t.views));
        }
    }
    Ok(())
}

/// The runtime's defaults at the photo's own size: these tables time the network at the
/// --size asked for, not at the runtime's default longest side.
fn at_full_size() -> NetOptions {
    NetOptions {
        max_side: None,
        ..NetOptions::default()
    }
}

#[cfg(test)]
mod tests;
