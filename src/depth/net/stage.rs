//! The depth stage around the network: its relative output mapped to scene depth
//! ([`SceneScale`]), the stage's options and report, and depth embedded in the photo
//! brought to the same scene scale.

use image::imageops::FilterType;
use image::RgbImage;

use crate::depth::embedded::{self as embedded_depth, Container, EmbeddedDepth, RangeFormat};
use crate::depth::refine::{self as depth_refine, RefineOptions};
use crate::depth::DepthMap;
use crate::engine::manifest::Precision;
use crate::engine::resample;
use crate::io::record::FileRecord;

use super::{DepthNet, DepthNetError, NetworkDepth, OutputKind};
pub use crate::depth::SceneScale;

/// How depth is estimated when no depth file is given: what the depth options of every
/// command that estimates depth describe.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthConfig {
    /// A manifest or an .onnx with its manifest beside it (`None`: the shipped model).
    pub model: Option<std::path::PathBuf>,
    /// Precision of the shipped model (int8 or fp32).
    pub precision: Precision,
    /// `tract`, or `ort` (a build with the `ort` feature).
    pub engine: String,
    /// `None`: every core.
    pub threads: Option<usize>,
    pub scale: SceneScale,
    /// Snap the upsampled depth's edges to the photo's.
    pub refine: bool,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self {
            model: None,
            precision: Precision::Fp32,
            engine: "tract".into(),
            threads: None,
            scale: SceneScale::default(),
            refine: true,
        }
    }
}

impl DepthConfig {
    /// The network to use.
    pub fn net(&self) -> super::NetChoice {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        super::NetChoice {
            model: self.model.clone(),
            precision: self.precision,
            engine: self.engine.clone(),
            threads: self.threads.unwrap_or(cores).max(1),
        }
    }

    /// The stage options, checked.
    pub fn options(&self) -> Result<StageOptions, crate::depth::ScaleError> {
        self.scale.check()?;
        Ok(StageOptions {
            scale: self.scale,
            refine: self.refine.then(RefineOptions::default),
        })
    }

    /// The estimator these settings describe; the network is loaded on first use.
    pub fn estimator(
        &self,
        source: super::DepthSource,
    ) -> Result<super::DepthEstimator, crate::depth::ScaleError> {
        Ok(super::DepthEstimator::new(
            source,
            self.net(),
            self.options()?,
        ))
    }
}

/// Settings of the depth stage that do not depend on where the depth comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageOptions {
    pub scale: SceneScale,
    /// Edge refinement after upsampling (None: off). A radius of 0 means "from the
    /// upsampling factor".
    pub refine: Option<RefineOptions>,
}

impl Default for StageOptions {
    fn default() -> Self {
        Self {
            scale: SceneScale::default(),
            refine: Some(RefineOptions::default()),
        }
    }
}

/// What the depth stage did, for the log and run.json.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StageReport {
    /// "network" or "embedded".
    pub source: &'static str,
    pub model: Option<String>,
    /// The network's ONNX file and its sha256 (verified against the manifest at load).
    pub model_file: Option<FileRecord>,
    pub precision: Option<Precision>,
    pub engine: Option<String>,
    pub output_kind: OutputKind,
    /// Size the depth had before upsampling (network input or embedded image).
    pub native_size: [usize; 2],
    pub embedded: Option<EmbeddedReport>,
    /// Why embedded depth present in the photo was not used.
    pub embedded_error: Option<String>,
    /// Relative disparity only: the percentiles mapped to near and far.
    pub disparity_percentiles: Option<[f32; 2]>,
    pub scene_scale: Option<SceneScale>,
    pub refine: Option<RefineOptions>,
    pub depth_range: [f32; 2],
    pub time_ms: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct EmbeddedReport {
    pub container: Container,
    pub format: RangeFormat,
    pub near: f32,
    pub far: f32,
    pub units: Option<String>,
    pub mime: String,
}

/// Scene depth for a photo from the network: estimate at the network's size, upsample
/// the disparity to `size` (the photo's, or the smaller size of the views it is for),
/// refine its edges with the photo, map it to scene depth (relative outputs through
/// `opts.scale`; metric depth keeps its units).
pub fn network_depth(
    net: &DepthNet,
    photo: &RgbImage,
    size: [usize; 2],
    opts: &StageOptions,
) -> Result<(DepthMap, StageReport), DepthNetError> {
    let started = std::time::Instant::now();
    let estimate = net.estimate(photo)?;
    Ok(scene_depth(net, &estimate, photo, size, opts, started))
}

/// The size of `photo`, for the stage functions' `size`.
pub fn photo_size(photo: &RgbImage) -> [usize; 2] {
    [photo.width() as usize, photo.height() as usize]
}

/// The rest of [`network_depth`] after the network: `estimate` (`net`'s output for
/// `photo`) upsampled to `size`, refined and scaled; the report's time counts from
/// `started`.
pub fn scene_depth(
    net: &DepthNet,
    estimate: &NetworkDepth,
    photo: &RgbImage,
    size: [usize; 2],
    opts: &StageOptions,
    started: std::time::Instant,
) -> (DepthMap, StageReport) {
    let native = [estimate.map.width, estimate.map.height];
    let (map, percentiles, refine) = finish(
        &estimate.disparity(),
        native,
        estimate.kind,
        photo,
        size,
        opts,
    );
    let m = net.manifest();
    let report = StageReport {
        source: "network",
        model: Some(format!("{} {}", m.name, m.version)),
        model_file: Some(FileRecord {
            path: net.model.model_path.display().to_string(),
            sha256: m.sha256.trim().to_ascii_lowercase(),
        }),
        precision: Some(m.precision),
        engine: Some(format!(
            "{} x{} threads",
            net.engine().name(),
            net.engine().threads()
        )),
        output_kind: estimate.kind,
        native_size: native,
        embedded: None,
        embedded_error: None,
        disparity_percentiles: percentiles,
        scene_scale: percentiles.map(|_| opts.scale),
        refine,
        depth_range: map.range(),
        time_ms: started.elapsed().as_secs_f64() * 1e3,
    };
    (map, report)
}

/// Scene depth from depth the photo carries (metric, kept in its units), upright as the
/// photo is shown, fitted to `size` (see [`network_depth`]) and refined like the
/// network's.
pub fn embedded_scene_depth(
    found: &EmbeddedDepth,
    photo: &RgbImage,
    size: [usize; 2],
    opts: &StageOptions,
) -> Result<(DepthMap, StageReport), String> {
    let started = std::time::Instant::now();
    let upright = embedded_depth::apply_orientation(&found.map, found.orientation);
    let (dw, dh) = (upright.width as f64, upright.height as f64);
    let photo_aspect = f64::from(photo.width()) / f64::from(photo.height());
    if ((dw / dh) / photo_aspect - 1.0).abs() > crate::depth::ASPECT_TOLERANCE {
        return Err(format!(
            "embedded depth is {}x{} but the photo is {}x{}: aspect ratios differ",
            upright.width,
            upright.height,
            photo.width(),
            photo.height()
        ));
    }
    let disparity: Vec<f32> = upright.values.iter().map(|&z| 1.0 / z).collect();
    let native = [upright.width, upright.height];
    let (map, _, refine) = finish(&disparity, native, OutputKind::Depth, photo, size, opts);
    let report = StageReport {
        source: "embedded",
        model: None,
        model_file: None,
        precision: None,
        engine: None,
        output_kind: OutputKind::Depth,
        native_size: native,
        embedded: Some(EmbeddedReport {
            container: found.container,
            format: found.format,
            near: found.near,
            far: found.far,
            units: found.units.clone(),
            mime: found.mime.clone(),
        }),
        embedded_error: None,
        disparity_percentiles: None,
        scene_scale: None,
        refine,
        depth_range: map.range(),
        time_ms: started.elapsed().as_secs_f64() * 1e3,
    };
    Ok((map, report))
}

type Finished = (DepthMap, Option<[f32; 2]>, Option<RefineOptions>);

/// Upsamples disparity to `size` (refining it on the way) and converts it to depth.
fn finish(
    disparity: &[f32],
    [w, h]: [usize; 2],
    kind: OutputKind,
    photo: &RgbImage,
    [pw, ph]: [usize; 2],
    opts: &StageOptions,
) -> Finished {
    let (up, refine) = match opts.refine {
        Some(r) => {
            let (up, r) = refined(disparity, (w, h), photo, (pw, ph), r);
            (up, Some(r))
        }
        None => (resample::resize(disparity, w, h, pw, ph), None),
    };
    if kind == OutputKind::Depth {
        let data = up.iter().map(|&d| 1.0 / d.max(f32::MIN_POSITIVE)).collect();
        return (DepthMap::new(pw, ph, data), None, refine);
    }
    let (map, p) = opts.scale.depth_from_disparity(pw, ph, &up);
    (map, Some(p), refine)
}

/// Refines at `(pw, ph)` or, when that is larger, at a working size of at most
/// `max_side` (the median's cost is per pixel), then upsamples to `(pw, ph)`: the
/// remaining blur is at most that many pixels over the working size's.
pub(crate) fn refined(
    disparity: &[f32],
    (w, h): (usize, usize),
    photo: &RgbImage,
    (pw, ph): (usize, usize),
    r: RefineOptions,
) -> (Vec<f32>, RefineOptions) {
    let k = (r.max_side.max(1) as f64 / pw.max(ph) as f64).min(1.0);
    let (ww, wh) = (
        ((pw as f64 * k).round() as usize).max(1),
        ((ph as f64 * k).round() as usize).max(1),
    );
    let guide = if (ww, wh) == (photo.width() as usize, photo.height() as usize) {
        photo.clone()
    } else {
        image::imageops::resize(photo, ww as u32, wh as u32, FilterType::Triangle)
    };
    let rgb: Vec<f32> = guide
        .as_raw()
        .iter()
        .map(|&v| f32::from(v) / 255.0)
        .collect();
    let r = match r.radius {
        0 => RefineOptions {
            radius: RefineOptions::radius_for(w.max(h), ww.max(wh)),
            ..r
        },
        _ => r,
    };
    let work = resample::resize(disparity, w, h, ww, wh);
    let work = depth_refine::refine_disparity(&rgb, &work, ww, wh, r);
    (resample::resize(&work, ww, wh, pw, ph), r)
}
