//! `reshader eval-relocation`: how well each relocation method predicts a rendered
//! novel view (the paper's Table 1, for our relocators).
//!
//! For every example of a rendered dataset (`<root>/<id>/{input,reshaded,novel}.exr,
//! depth.exr, mask.png, meta.json`, the dataset renderer's layout) the ground-truth
//! depth and the novel camera (`meta.json` "novel_offset", same orientation and
//! intrinsics as the input camera) are given to each method:
//!
//! - **input**: the input image itself, unmoved (the floor any method must beat);
//! - **mesh-warp**: [`MeshWarp`], the first forward-warp renderer;
//! - **ldi**: the layered depth image ([`Ldi`]) as the runtime configures it.
//!
//! each once with the input's colours (relocation alone) and once with the rendered
//! `reshaded.exr` (relocation + reshading, with the renderer's ground-truth reshading:
//! an upper bound for the network). The LDI is also scored with the colours of the
//! reshading model (`--model`, as `render` takes it; the shipped one by default): the
//! full novel view the runtime would show, against relocation alone. With the rendered
//! reshaded colours the LDI is also scored with
//! its background band keeping the colours inpainted from the input
//! ([`BandColours::Inpainted`]) instead of taking them from the view's reshaded image. PSNR and SSIM are computed against `novel.exr`
//! over valid pixels (mask.png), split into pixels the input sees (the LDI renders them
//! entirely from original pixels) and the disoccluded band (entirely from inpainted
//! background or hole filling); PSNR also in the [`regions`] the true geometry gives (the
//! band around depth edges, what occluders uncover, what lies beyond the frame).
//! `--depth-source network` ([`EvalDepth`]) gives the methods the depth network's depth,
//! aligned to the true depth by least squares in disparity, instead of the true depth.
//! HDR images are tone-mapped with a fixed exposure and gamma (×5.5, 1/2.2, clipped: the training evaluation's), depth +inf (sky) becomes
//! [`SKY_DEPTH`].

mod example;
mod network_depth;
pub mod regions;

pub use network_depth::{EvalDepth, COARSE_FACTOR};

use example::{example_dirs, load_example, Example};

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::depth::net::{DepthNet, DepthNetError};
use crate::depth::DepthMap;
use crate::io::photo::SrgbImage;
use crate::relocate::ldi::{view_reach, BandColours, Border, Ldi, LdiConfig, Silhouettes};
use crate::relocate::{MeshWarp, RelocateError, Relocator};
use crate::reshade::net::choice::ReshadeConfig;
use crate::reshade::net::NetError;
use crate::reshade::{ReshadeError, Reshader};
use crate::views::ViewCamera;

/// Images per row of a contact sheet.
pub const SHEET_COLUMNS: usize = 4;

/// Depth given to pixels that see the sky (+inf in depth.exr), in scene units.
pub const SKY_DEPTH: f32 = 1000.0;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("reshading model: {0}")]
    Model(#[from] NetError),
    #[error("depth network: {0}")]
    DepthModel(#[from] DepthNetError),
    #[error("{id}: depth network: {source}")]
    Depth { id: String, source: DepthNetError },
    #[error("{id}: {source}")]
    Reshade { id: String, source: ReshadeError },
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot decode {path}: {source}")]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: {detail}")]
    Meta { path: PathBuf, detail: String },
    #[error("{path}: {source}")]
    DepthFile {
        path: PathBuf,
        source: crate::depth::DepthError,
    },
    #[error("{id}: {source}")]
    Relocate { id: String, source: RelocateError },
    #[error("no complete examples (folders with meta.json) under {0}")]
    Empty(PathBuf),
}

/// What `eval-relocation` scores and where it writes.
#[derive(Clone, Debug)]
pub struct EvalConfig {
    /// A dataset split folder (one folder per example).
    pub data: PathBuf,
    /// At most this many examples, in name order.
    pub limit: Option<usize>,
    /// The tone mapping of the HDR renders.
    pub exposure: f32,
    pub gamma: f32,
    /// What the LDI shows beyond the photo's borders.
    pub border: Border,
    /// How the LDI draws the pixels that mix the two sides of a depth step.
    pub silhouettes: Silhouettes,
    pub band_smoothing: usize,
    /// Depth the methods relocate with: the renderer's, or the shipped depth network's
    /// scale-aligned to it in disparity.
    pub depth_source: EvalDepth,
    /// With `EvalDepth::Network`: this depth model instead of the shipped one.
    pub depth_model: Option<PathBuf>,
    /// How much coarser than the photo `EvalDepth::Coarse` makes the true depth.
    pub coarse_factor: f64,
    /// Where the per-example numbers go as JSON.
    pub json: Option<PathBuf>,
    /// Where the contact sheets go, one PNG per example.
    pub sheets: Option<PathBuf>,
    /// The reshading model whose colours the LDI also relocates.
    pub reshade: ReshadeConfig,
}

/// Where a method's colours come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Colours {
    /// The input photo's: relocation alone.
    Input,
    /// The renderer's ground-truth reshaded image: an upper bound for any network.
    Truth,
    /// The reshading model's, as the runtime computes them.
    Network,
}

impl Colours {
    fn label(self) -> &'static str {
        match self {
            Colours::Input => "input",
            Colours::Truth => "reshaded (rendered GT)",
            Colours::Network => "reshaded (network)",
        }
    }
}

/// PSNR (dB) and SSIM over one region; `None` when the region is empty.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Score {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub pixels: usize,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct MethodScore {
    pub method: &'static str,
    pub colours: Colours,
    pub all: Score,
    pub visible: Score,
    pub disoccluded: Score,
    /// Within [`regions::EDGE_BAND_PX`] of a true depth step.
    pub edge: Score,
    /// Hidden by an occluder in the input (true geometry).
    pub uncovered: Score,
    /// Beyond the input's frame (true geometry).
    pub border: Score,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ExampleReport {
    pub id: String,
    pub size: [u32; 2],
    pub novel_offset: [f64; 3],
    pub scores: Vec<MethodScore>,
    pub ldi_build_ms: f64,
    pub ldi_render_ms: f64,
    pub mesh_warp_render_ms: f64,
}

/// Evaluates every complete example under `args.data`; returns the per-example reports
/// and the table of their means.
pub fn run(args: &EvalConfig) -> Result<(Vec<ExampleReport>, String), EvalError> {
    let dirs = example_dirs(&args.data, args.limit)?;
    let reshader = args.reshade.build()?;
    let depth_net = match args.depth_source {
        EvalDepth::Network => Some(network_depth::load(args.depth_model.as_deref())?),
        EvalDepth::Truth | EvalDepth::Coarse => None,
    };
    let mut reports = Vec::new();
    for dir in &dirs {
        let mut example = load_example(dir, args.exposure, args.gamma)?;
        if let Some(net) = &depth_net {
            example.depth = estimated_depth(net, &example)?;
        }
        if args.depth_source == EvalDepth::Coarse {
            example.depth =
                network_depth::coarsened(&example.input, &example.true_depth, args.coarse_factor);
        }
        let ldi = LdiConfig {
            border: args.border,
            silhouettes: args.silhouettes,
            band_smoothing: args.band_smoothing,
            ..LdiConfig::default()
        };
        let (report, sheet) = evaluate(&example, &ldi, reshader.as_ref())?;
        log::info!(
            "{}: {}",
            report.id,
            serde_json::to_string(&report.scores).unwrap_or_default()
        );
        if let Some(out) = &args.sheets {
            write_sheet(out, &report.id, &sheet)?;
        }
        reports.push(report);
    }
    let table = table(&reports, args, &reshader.description());
    if let Some(path) = &args.json {
        let json = serde_json::to_vec_pretty(&reports).expect("reports serialise");
        crate::io::output::write_atomic(path, &json).map_err(|e| EvalError::Meta {
            path: path.clone(),
            detail: e.to_string(),
        })?;
    }
    Ok((reports, table))
}

fn estimated_depth(net: &DepthNet, ex: &Example) -> Result<DepthMap, EvalError> {
    network_depth::estimate(net, &ex.input, &ex.true_depth, &ex.valid).map_err(|source| {
        EvalError::Depth {
            id: ex.id.clone(),
            source,
        }
    })
}

/// The regions of [`regions::Regions`] for one example, from a render of the LDI of its
/// true depth with the border not extended.
fn true_regions(ex: &Example, view: &ViewCamera) -> Result<regions::Regions, RelocateError> {
    let config = LdiConfig {
        border: Border::Inpaint,
        silhouettes: Silhouettes::Hard,
        ..LdiConfig::default()
    };
    let reach = view_reach(ex.offset, &ex.source);
    let truth = Ldi::build(&ex.input, &ex.true_depth, &ex.source, &config, reach)?
        .render_detailed(&ex.input, view)?;
    Ok(regions::Regions::of_truth(
        &ex.true_depth,
        &ex.source,
        ex.offset,
        &truth.front_fraction,
        &truth.hole_fraction,
    ))
}

/// Scores every method on one example; also returns the relocation-alone images for a sheet.
/// The dataset's depth and offsets are already in training units.
fn evaluate(
    ex: &Example,
    config: &LdiConfig,
    reshader: &dyn Reshader,
) -> Result<(ExampleReport, Vec<SrgbImage>), EvalError> {
    let fail = |source| EvalError::Relocate {
        id: ex.id.clone(),
        source,
    };
    let network = reshader
        .prepare(&ex.input, &ex.depth, &ex.source)
        .and_then(|photo| photo.reshade(ex.offset))
        .map_err(|source| EvalError::Reshade {
            id: ex.id.clone(),
            source,
        })?;
    let view = ViewCamera {
        centre: ex.offset,
        intrinsics: ex.source,
    };
    let start = Instant::now();
    let ldi = Ldi::build(
        &ex.input,
        &ex.depth,
        &ex.source,
        config,
        view_reach(ex.offset, &ex.source),
    )
    .map_err(fail)?;
    let ldi_build_ms = ms(start);
    let start = Instant::now();
    let plain = ldi.render_detailed(&ex.input, &view).map_err(fail)?;
    let ldi_render_ms = ms(start);
    let visible: Vec<bool> = plain
        .front_fraction
        .iter()
        .zip(&ex.valid)
        .map(|(&f, &v)| v && f == 1.0)
        .collect();
    let disoccluded: Vec<bool> = plain
        .front_fraction
        .iter()
        .zip(&ex.valid)
        .map(|(&f, &v)| v && f == 0.0)
        .collect();
    let start = Instant::now();
    let warp_plain = MeshWarp::default()
        .render(&ex.input, &ex.depth, &ex.source, &view)
        .map_err(fail)?;
    let mesh_warp_render_ms = ms(start);
    let warp_reshaded = MeshWarp::default()
        .render(&ex.reshaded, &ex.depth, &ex.source, &view)
        .map_err(fail)?;
    let ldi_reshaded = ldi.render(&ex.reshaded, &view).map_err(fail)?;
    let ldi_network = ldi.render(&network, &view).map_err(fail)?;
    let inpainted_config = LdiConfig {
        band_colours: BandColours::Inpainted,
        ..config.clone()
    };
    let ldi_inpainted = Ldi::build(
        &ex.input,
        &ex.depth,
        &ex.source,
        &inpainted_config,
        view_reach(ex.offset, &ex.source),
    )
    .and_then(|l| l.render(&ex.reshaded, &view))
    .map_err(fail)?;
    let truth = true_regions(ex, &view).map_err(fail)?;
    let valid = |mask: &[bool]| -> Vec<bool> {
        mask.iter().zip(&ex.valid).map(|(&m, &v)| m && v).collect()
    };
    let (edge, uncovered, border_px) = (
        valid(&truth.edge),
        valid(&truth.uncovered),
        valid(&truth.border),
    );
    let predictions: [(&'static str, Colours, &SrgbImage); 8] = [
        ("input", Colours::Input, &ex.input),
        ("input", Colours::Truth, &ex.reshaded),
        ("mesh-warp", Colours::Input, &warp_plain),
        ("mesh-warp", Colours::Truth, &warp_reshaded),
        ("ldi", Colours::Input, &plain.image),
        ("ldi", Colours::Truth, &ldi_reshaded),
        (
            "ldi, band keeps inpainted colours",
            Colours::Truth,
            &ldi_inpainted,
        ),
        ("ldi", Colours::Network, &ldi_network),
    ];
    let scores = predictions
        .iter()
        .map(|&(method, colours, prediction)| {
            let ssim = ssim_map(prediction, &ex.novel);
            let score = |mask: &[bool]| region_score(prediction, &ex.novel, &ssim, mask);
            MethodScore {
                method,
                colours,
                all: score(&ex.valid),
                visible: score(&visible),
                disoccluded: score(&disoccluded),
                edge: score(&edge),
                uncovered: score(&uncovered),
                border: score(&border_px),
            }
        })
        .collect();
    let band = highlight(&ldi_reshaded, &disoccluded);
    let sheet = vec![
        ex.input.clone(),
        warp_plain,
        plain.image,
        ex.novel.clone(),
        ex.reshaded.clone(),
        warp_reshaded,
        ldi_reshaded,
        band,
    ];
    let report = ExampleReport {
        id: ex.id.clone(),
        size: [ex.source.width, ex.source.height],
        novel_offset: ex.offset,
        scores,
        ldi_build_ms,
        ldi_render_ms,
        mesh_warp_render_ms,
    };
    Ok((report, sheet))
}

/// Per example, the PSNR of the LDI with the network's colours minus the LDI with the
/// input's (over valid pixels); `None` when no example has both.
pub fn network_gain(reports: &[ExampleReport]) -> Option<Vec<f64>> {
    let psnr = |r: &ExampleReport, colours| {
        r.scores
            .iter()
            .find(|s| s.method == "ldi" && s.colours == colours)
            .and_then(|s| s.all.psnr)
    };
    let gains: Vec<f64> = reports
        .iter()
        .filter_map(|r| Some(psnr(r, Colours::Network)? - psnr(r, Colours::Input)?))
        .collect();
    (!gains.is_empty()).then_some(gains)
}

/// `image` with the pixels of `mask` tinted magenta.
fn highlight(image: &SrgbImage, mask: &[bool]) -> SrgbImage {
    let mut out = image.clone();
    let w = image.width() as usize;
    for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        let (x, y) = ((i % w) as u32, (i / w) as u32);
        let [r, g, b] = out.get(x, y);
        out.put(x, y, [0.5 + 0.5 * r, 0.5 * g, 0.5 + 0.5 * b]);
    }
    out
}

fn ms(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

fn region_score(a: &SrgbImage, b: &SrgbImage, ssim: &[f32], mask: &[bool]) -> Score {
    let pixels = mask.iter().filter(|&&m| m).count();
    if pixels == 0 {
        return Score::default();
    }
    let (mut se, mut ss) = (0.0f64, 0.0f64);
    for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        for c in 0..3 {
            se += f64::from(a.data()[3 * i + c] - b.data()[3 * i + c]).powi(2);
        }
        ss += f64::from(ssim[i]);
    }
    let mse = (se / (3 * pixels) as f64).max(1e-12);
    Score {
        psnr: Some(super::stats::psnr_from_mse(mse)),
        ssim: Some(ss / pixels as f64),
        pixels,
    }
}

/// Per-pixel SSIM (mean over channels) with an 11-tap Gaussian window, σ = 1.5,
/// renormalised at the borders.
pub fn ssim_map(a: &SrgbImage, b: &SrgbImage) -> Vec<f32> {
    let (w, h) = (a.width() as usize, a.height() as usize);
    let (c1, c2) = (0.01f32.powi(2), 0.03f32.powi(2));
    let mut out = vec![0.0; w * h];
    for c in 0..3 {
        let x: Vec<f32> = (0..w * h).map(|i| a.data()[3 * i + c]).collect();
        let y: Vec<f32> = (0..w * h).map(|i| b.data()[3 * i + c]).collect();
        let product =
            |p: &[f32], q: &[f32]| p.iter().zip(q).map(|(u, v)| u * v).collect::<Vec<f32>>();
        let (mx, my) = (blur(&x, w, h), blur(&y, w, h));
        let (sxx, syy, sxy) = (
            blur(&product(&x, &x), w, h),
            blur(&product(&y, &y), w, h),
            blur(&product(&x, &y), w, h),
        );
        for i in 0..w * h {
            let (vx, vy, cov) = (
                sxx[i] - mx[i] * mx[i],
                syy[i] - my[i] * my[i],
                sxy[i] - mx[i] * my[i],
            );
            let s = ((2.0 * mx[i] * my[i] + c1) * (2.0 * cov + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
            out[i] += s / 3.0;
        }
    }
    out
}

fn blur(v: &[f32], w: usize, h: usize) -> Vec<f32> {
    let taps: Vec<f32> = (-5i32..=5)
        .map(|k| (-(k * k) as f32 / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let pass = |src: &[f32], horizontal: bool| {
        let mut dst = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut sum, mut weight) = (0.0, 0.0);
                for (t, &g) in taps.iter().enumerate() {
                    let k = t as i64 - 5;
                    let (sx, sy) = if horizontal {
                        (x as i64 + k, y as i64)
                    } else {
                        (x as i64, y as i64 + k)
                    };
                    if sx >= 0 && sy >= 0 && sx < w as i64 && sy < h as i64 {
                        sum += g * src[sy as usize * w + sx as usize];
                        weight += g;
                    }
                }
                dst[y * w + x] = sum / weight;
            }
        }
        dst
    };
    pass(&pass(v, true), false)
}

/// Lays `images` out in rows of [`SHEET_COLUMNS`].
fn write_sheet(dir: &Path, id: &str, images: &[SrgbImage]) -> Result<(), EvalError> {
    let (w, h) = (images[0].width(), images[0].height());
    let rows = images.len().div_ceil(SHEET_COLUMNS) as u32;
    let mut sheet = image::RgbImage::new(w * SHEET_COLUMNS as u32, h * rows);
    for (k, img) in images.iter().enumerate() {
        let (col, row) = ((k % SHEET_COLUMNS) as i64, (k / SHEET_COLUMNS) as i64);
        image::imageops::replace(
            &mut sheet,
            &img.to_rgb8(),
            i64::from(w) * col,
            i64::from(h) * row,
        );
    }
    let path = dir.join(format!("{id}.png"));
    let io = |e: String| EvalError::Meta {
        path: path.clone(),
        detail: e,
    };
    std::fs::create_dir_all(dir).map_err(|e| io(e.to_string()))?;
    let bytes = crate::io::output::encode_png(&path, &sheet).map_err(|e| io(e.to_string()))?;
    crate::io::output::write_atomic(&path, &bytes).map_err(|e| io(e.to_string()))
}

/// The depth source as the table's header names it, with the coarsening factor.
fn depth_label(args: &EvalConfig) -> String {
    match args.depth_source {
        EvalDepth::Coarse => format!("Coarse (x{})", args.coarse_factor),
        other => format!("{other:?}"),
    }
}

/// The Table-1-style summary: mean PSNR / SSIM per method over all examples, then what
/// the reshading model adds to the LDI's novel views.
pub fn table(reports: &[ExampleReport], args: &EvalConfig, model: &str) -> String {
    let mut out = format!(
        "{} examples, {} depth, tone mapping x{} gamma {}, LDI border {}, {} silhouettes, band smoothed over {} px, reshading model {model}; PSNR dB / SSIM against the ground-truth novel view; PSNR dB in the true geometry's regions\n\n",
        reports.len(),
        depth_label(args),
        args.exposure,
        args.gamma,
        args.border,
        args.silhouettes,
        args.band_smoothing
    );
    out.push_str(
        "| method | colours | all | visible in input | disoccluded | edge band | uncovered | border |\n|---|---|---|---|---|---|---|---|\n",
    );
    let Some(first) = reports.first() else {
        return out;
    };
    for (k, s) in first.scores.iter().enumerate() {
        let mean = |pick: fn(&MethodScore) -> Score| {
            let scores: Vec<Score> = reports.iter().map(|r| pick(&r.scores[k])).collect();
            let avg = |f: fn(&Score) -> Option<f64>| {
                let v: Vec<f64> = scores.iter().filter_map(f).collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            };
            match (avg(|s| s.psnr), avg(|s| s.ssim)) {
                (Some(p), Some(q)) => format!("{p:.2} / {q:.4}"),
                (Some(p), None) => format!("{p:.2}"),
                _ => "–".into(),
            }
        };
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            s.method,
            s.colours.label(),
            mean(|m| m.all),
            mean(|m| m.visible),
            mean(|m| m.disoccluded),
            mean(|m| Score {
                ssim: None,
                ..m.edge
            }),
            mean(|m| Score {
                ssim: None,
                ..m.uncovered
            }),
            mean(|m| Score {
                ssim: None,
                ..m.border
            }),
        ));
    }
    let n = reports.len() as f64;
    if let Some(gain) = network_gain(reports) {
        out.push_str(&format!(
            "\nreshading in full novel views (LDI + network against LDI alone, valid pixels): {:+.2} dB mean over {} examples, {} improved\n",
            gain.iter().sum::<f64>() / gain.len() as f64,
            gain.len(),
            gain.iter().filter(|&&g| g > 0.0).count()
        ));
    }
    out.push_str(&format!(
        "\nLDI build {:.1} ms, LDI render {:.1} ms/view, mesh-warp render {:.1} ms/view (means, {}x{})\n",
        reports.iter().map(|r| r.ldi_build_ms).sum::<f64>() / n,
        reports.iter().map(|r| r.ldi_render_ms).sum::<f64>() / n,
        reports.iter().map(|r| r.mesh_warp_render_ms).sum::<f64>() / n,
        first.size[0],
        first.size[1]
    ));
    out
}
