//! Option groups several subcommands share (flattened into their arguments), and the
//! conversions from them to the library's settings.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Args;

use reshader::depth::holes::HolePolicy;
use reshader::depth::net::{DepthConfig, DepthSource, SceneScale};
use reshader::depth::DepthKind;
use reshader::engine::manifest::Precision;
use reshader::interleave::{Blend, Board};
use reshader::io::keyword::Keyword;
use reshader::pipeline::{Scene, SceneDepth};
use reshader::relocate::ldi::{Border, Silhouettes, BAND_SMOOTHING_PX};
use reshader::relocate::{RelocateConfig, RelocateKind};
use reshader::reshade::net::choice::{Head, ReshadeConfig};

/// A parser for a library type chosen by name: its names are the possible values `--help`
/// lists and the shell completes.
pub fn keyword<T: Keyword + Send + Sync>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(T::ALL.iter().map(|(_, name)| *name))
        .map(|name| T::from_keyword(&name).expect("clap passes only the possible values"))
}

/// The photo and where its depth and shading come from: `render`, `view`, `reshade`, `sheet`.
#[derive(Args)]
pub struct SceneArgs {
    /// The photo (JPEG or PNG).
    pub photo: PathBuf,
    /// Where depth comes from: auto (the depth the photo carries, else the depth network),
    /// network, embedded (an error if the photo has none), or a depth file: .npy
    /// (float32/float16/uint16), 16-bit .png (thousandths of a unit), .pfm or .exr.
    #[arg(long, default_value = "auto", value_name = "FILE|auto|...")]
    pub depth: DepthInput,
    /// How to read a depth file: depth in scene units, or relative disparity (larger =
    /// nearer), normalised so the scene spans depth 1 to 5 units [default: depth].
    #[arg(long, value_parser = keyword::<DepthKind>())]
    pub depth_kind: Option<DepthKind>,
    /// Holes in a depth file (0, NaN or infinite values, where a sensor or renderer had
    /// no depth): refuse the file, put them at the farthest depth (far: skies), or fill
    /// them from their neighbours, following the photo's colour edges [default: refuse].
    #[arg(long, value_parser = keyword::<HolePolicy>())]
    pub depth_holes: Option<HolePolicy>,
    /// Horizontal field of view in degrees [default: from EXIF 35 mm focal length, else 45].
    #[arg(long, allow_negative_numbers = true)]
    pub fov: Option<f64>,
    /// Depth of the zero-parallax plane, in depth-map units [default: robust middle depth].
    #[arg(long, allow_negative_numbers = true)]
    pub focus: Option<f64>,
    #[command(flatten)]
    pub reshade: ReshadeArgs,
    #[command(flatten)]
    pub estimate: EstimateArgs,
}

impl SceneArgs {
    /// The depth file, or an estimator (the network is loaded only when used).
    pub fn scene_depth(&self) -> Result<SceneDepth> {
        match &self.depth {
            DepthInput::File(path) => Ok(SceneDepth::File {
                path: path.clone(),
                kind: self.depth_kind.unwrap_or(DepthKind::Depth),
                holes: self.depth_holes.unwrap_or_default(),
            }),
            DepthInput::Estimate(_) if self.depth_kind.is_some() => Err(anyhow::anyhow!(
                "--depth-kind says how to read a depth file; give the file with --depth FILE"
            )),
            DepthInput::Estimate(_) if self.depth_holes.is_some() => Err(anyhow::anyhow!(
                "--depth-holes says what to do with holes in a depth file; give the file \
                 with --depth FILE"
            )),
            DepthInput::Estimate(source) => Ok(SceneDepth::Estimate(Arc::new(
                self.estimate.config().estimator(*source)?,
            ))),
        }
    }

    /// Whether depth will come from the network (no depth file).
    pub fn estimates_depth(&self) -> bool {
        !matches!(self.depth, DepthInput::File(_))
    }

    /// The photo and its depth, loaded; with `views` (their size), estimated depth at
    /// the size the photo is fitted to for them (see `Scene::load`).
    pub fn load(&self, views: Option<(u32, u32)>) -> Result<Scene> {
        let depth = self.scene_depth()?;
        let mut timings = reshader::io::record::Timings::default();
        Ok(Scene::load(
            &self.photo,
            &depth,
            self.fov,
            views,
            &mut timings,
        )?)
    }
}

/// `--depth` of the rendering commands: a file, or where to get depth without one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DepthInput {
    File(PathBuf),
    Estimate(DepthSource),
}

impl std::str::FromStr for DepthInput {
    type Err = String;

    /// `auto`, `network` and `embedded` are keywords (a file of that name: `./auto`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.is_empty() {
            return Err("expected a depth file or auto, network, embedded".into());
        }
        Ok(match DepthSource::from_keyword(s) {
            Some(source) => DepthInput::Estimate(source),
            None => DepthInput::File(PathBuf::from(s)),
        })
    }
}

/// The depth stage's options: `reshader depth`, and the depth estimation of the commands
/// that render.
#[derive(Clone, Debug, Args)]
pub struct DepthStageArgs {
    /// Depth model: an .onnx file with its .json manifest beside it (same stem), or the
    /// manifest. Default: the shipped Tiefenrausch model (models/depth: the tuned
    /// tiefenrausch-tuned-fp32, or the original tiefenrausch-int8 at --depth-precision
    /// int8; found in the working directory or beside the binary, or in the directory
    /// $RESHADER_DEPTH_MODELS).
    #[arg(long)]
    pub depth_model: Option<PathBuf>,
    /// Inference engine for the depth network: tract, or ort (needs --features ort).
    #[arg(long, default_value = "tract")]
    pub depth_engine: String,
    /// Threads for the depth network (default: every core).
    #[arg(long)]
    pub depth_threads: Option<usize>,
    /// Scene depth given to the near end of relative depth (its 98th disparity percentile).
    #[arg(long, default_value_t = reshader::depth::NEAR, allow_negative_numbers = true)]
    pub near: f32,
    /// The far end of relative depth (2nd disparity percentile) lands at near + this.
    #[arg(long, default_value_t = reshader::depth::FAR - reshader::depth::NEAR, allow_negative_numbers = true)]
    pub depth_budget: f32,
    /// Keep the upsampled depth as it is (no edge refinement with the photo).
    #[arg(long)]
    pub no_depth_refine: bool,
}

impl DepthStageArgs {
    pub fn config(&self, precision: Precision) -> DepthConfig {
        DepthConfig {
            model: self.depth_model.clone(),
            precision,
            engine: self.depth_engine.clone(),
            threads: self.depth_threads,
            scale: SceneScale {
                near: self.near,
                budget: self.depth_budget,
            },
            refine: !self.no_depth_refine,
        }
    }
}

/// The depth-estimation options of the commands that render (`render`, `view`,
/// `reshade`, `convert`, `watch`, `live`), used when no depth file is given.
#[derive(Clone, Debug, Args)]
#[command(next_help_heading = "Depth estimation (when no depth file is given)")]
pub struct EstimateArgs {
    /// Precision of the shipped depth model: fp32 (faster in tract, and tuned on renders
    /// for cleaner depth edges) or int8 (smaller; the original, untuned network).
    #[arg(long, default_value = "fp32", value_parser = parse_depth_precision)]
    pub depth_precision: Precision,
    #[command(flatten)]
    pub stage: DepthStageArgs,
}

impl EstimateArgs {
    pub fn config(&self) -> DepthConfig {
        self.stage.config(self.depth_precision)
    }
}

/// `--key-views`: a count of key views, or every view (`all`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyViews(pub Option<usize>);

pub fn parse_key_views(s: &str) -> Result<KeyViews, String> {
    if s == "all" {
        return Ok(KeyViews(None));
    }
    match s.parse::<usize>() {
        Ok(k) if k >= 2 => Ok(KeyViews(Some(k))),
        _ => Err(format!(
            "`{s}` is neither `all` nor a count of at least 2 (the two outermost views are always keys)"
        )),
    }
}

/// `--reshade-size`: a longest side in pixels, or None for `full`.
#[derive(Clone, Copy, Debug)]
pub struct ReshadeSize(pub Option<usize>);

pub fn parse_reshade_size(s: &str) -> Result<ReshadeSize, String> {
    if s == "full" {
        return Ok(ReshadeSize(None));
    }
    match s.parse::<usize>() {
        Ok(px) if px >= 1 => Ok(ReshadeSize(Some(px))),
        _ => Err(format!(
            "`{s}` is neither `full` nor a size in pixels of at least 1 (the network's longest side)"
        )),
    }
}

/// Parses the precision of the depth models (only int8 and fp32 are shipped).
pub fn parse_depth_precision(s: &str) -> Result<Precision, String> {
    match s.parse::<Precision>()? {
        Precision::Fp16 => Err("the depth models ship as int8 and fp32".into()),
        p => Ok(p),
    }
}

/// The options that choose and tune the reshading network.
#[derive(Clone, Debug, Args)]
pub struct ReshadeArgs {
    /// Reshading model: a manifest (.json; the single graph, or either half of an
    /// encoder/decoder pair) or a directory of them, or `none` to keep the photo's
    /// shading. Default: $RESHADER_MODEL, else the shipped models/reshade (found in the
    /// working directory, under $RESHADER_MODELS, or beside the binary).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Model precision to load: int8 (the default for a model directory: a quarter of
    /// fp32's weight bytes, at about fp32's speed in tract, which turns the int8
    /// weights into f32 once at load), fp32 or fp16. A --model manifest file is loaded at
    /// its own precision unless this is given. The model must have been exported at that
    /// precision; fp16 weights are computed in f32 on CPUs without fp16 arithmetic.
    #[arg(long, value_parser = |s: &str| s.parse::<Precision>())]
    pub precision: Option<Precision>,
    /// Inference engine: tract (built in), or ort (onnxruntime from $ORT_DYLIB_PATH; needs
    /// a build with --features ort).
    #[arg(long, default_value = "tract")]
    pub engine: String,
    /// Working resolution of the network as a fraction of the photo's; the predicted
    /// residual is upsampled to full resolution.
    #[arg(long, default_value_t = 1.0)]
    pub reshade_scale: f64,
    /// The network's working resolution at most this many pixels on its longest side
    /// (the photo is shrunk for the network and the residual upsampled), or `full`: the
    /// photo's working size. The shipped model, trained on 128-pixel scenes, gains twice
    /// as much where shading changes at 256 px as at 640 px on rendered scenes, and a 12 MP
    /// photo's Portrait views decode about six times faster (docs/reshading.md,
    /// "Working size").
    #[arg(long, value_name = "PX|full", default_value = "256", value_parser = parse_reshade_size)]
    pub reshade_size: ReshadeSize,
    /// Run the network for this many views (the outermost two among them) and blend the
    /// residual of the others from the two key views beside them, or `all` to run it for
    /// every view (several times slower; the blend costs nothing measurable on rendered
    /// truth, docs/reshading.md).
    #[arg(long, value_name = "N|all", default_value = "8", value_parser = parse_key_views)]
    pub key_views: KeyViews,
    /// Views per decoder call.
    #[arg(long, default_value_t = 1)]
    pub reshade_batch: usize,
    /// Views decoded at the same time, each on its own thread (the engine then uses
    /// --reshade-threads / this many threads per view).
    #[arg(long, default_value_t = 1)]
    pub parallel_views: usize,
    /// Threads for reshading (default: every core).
    #[arg(long)]
    pub reshade_threads: Option<usize>,
    /// Reshading head: residual (the paper's network, run per view) or lobes (a network
    /// run once per photo and a closed form per view; also the lobes-slide models, whose
    /// closed form adds a sliding reflection layer). Default: a --model manifest's own
    /// head; for a directory, residual when it holds residual-head models, else lobes.
    #[arg(long, value_parser = keyword::<Head>())]
    pub head: Option<Head>,
    /// Residual head: a view whose predicted change touches under this share of its
    /// pixels by more than one 8-bit level keeps the photo exactly (the network's noise on
    /// a view whose shading does not move, as in whole matte scenes); 0 keeps every view as
    /// predicted (docs/reshading.md, "The gate").
    #[arg(long, value_name = "SHARE", default_value_t = reshader::reshade::net::DEFAULT_VIEW_GATE)]
    pub reshade_gate: f64,
}

impl ReshadeArgs {
    pub fn config(&self) -> ReshadeConfig {
        ReshadeConfig {
            model: self.model.clone(),
            precision: self.precision,
            engine: self.engine.clone(),
            scale: self.reshade_scale,
            max_side: self.reshade_size.0,
            key_views: self.key_views.0,
            batch: self.reshade_batch,
            parallel_views: self.parallel_views,
            threads: self.reshade_threads,
            head: self.head,
            gate: self.reshade_gate,
        }
    }

    /// Refuses a `--model` that names the wrong kind of file before anything loads.
    pub fn check_model(&self) -> Result<()> {
        if let Some(model) =
            reshader::pipeline::preflight::chosen_reshade_model(self.model.as_deref())
        {
            reshader::pipeline::preflight::check_model_path("--model", &model)?;
        }
        Ok(())
    }
}

/// How views are relocated: `render`, `view`, `sheet`, `convert`, `watch`, `live`, `bench`.
#[derive(Clone, Debug, Args)]
pub struct RelocateArgs {
    /// Relocation method: the layered depth image, or the first mesh warp (for comparison).
    #[arg(long = "relocate", value_parser = keyword::<RelocateKind>(), default_value = "ldi")]
    pub kind: RelocateKind,
    /// Beyond the photo's borders (LDI): magnify every view by one factor, just enough
    /// that no view sees past the photo's edge (1 where none would: a photo wider than
    /// the view, a focus plane at the border's depth), stretch the border pixels
    /// outwards (the input's framing, streaks at the edge of outer views), or fill what
    /// a view sees beyond the border by patch synthesis from the view.
    #[arg(long, value_parser = keyword::<Border>(), default_value = "crop")]
    pub border: Border,
    /// The pixels either side of a depth step that mix an object and its background
    /// (LDI): their foreground share, estimated from the colours on either side, moves
    /// with the object over what each view sees behind it (no rim of the photo's
    /// background follows the object, no ghost of it stays behind), or each pixel goes
    /// wholly to its side. `live` always draws them hard.
    #[arg(long, value_parser = keyword::<Silhouettes>(), default_value = "soft")]
    pub silhouettes: Silhouettes,
    /// Radius in pixels of the box over which the background inpainted behind each
    /// occluder (LDI) is averaged with the surface around it: synthesised texture is
    /// plausible but not what was hidden, and its mean is nearer; 0 keeps the texture as
    /// synthesised. `live` never smooths.
    #[arg(long, default_value_t = BAND_SMOOTHING_PX, value_name = "PX")]
    pub band_smoothing: usize,
}

impl RelocateArgs {
    pub fn config(&self) -> RelocateConfig {
        RelocateConfig {
            kind: self.kind,
            border: self.border,
            silhouettes: self.silhouettes,
            band_smoothing: self.band_smoothing,
        }
    }
}

/// How views are filtered when weaving; each option overrides the board's `[filter]`.
#[derive(Args)]
pub struct FilterArgs {
    /// Subpixels between view centres: the nearest view, a linear mix of the two nearest,
    /// or a Gaussian over the three nearest [default: the board's, else nearest].
    #[arg(long, value_parser = keyword::<Blend>())]
    pub blend: Option<Blend>,
    /// Darken this fraction of the view cone at each end (0 to 0.5), so that the jump
    /// where the cone wraps shows as a dark seam [default: the board's, else 0].
    #[arg(long, value_name = "FRACTION")]
    pub dim_edges: Option<f64>,
}

impl FilterArgs {
    pub fn apply(&self, board: &mut Board) -> Result<()> {
        let mut filter = board.filter();
        if let Some(blend) = self.blend {
            filter.blend = blend;
        }
        if let Some(dim) = self.dim_edges {
            filter.dim_edges = dim;
        }
        Ok(board.set_filter(filter)?)
    }
}

/// Parses TX,TY,TZ.
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("expected TX,TY,TZ (three numbers), got '{s}'"));
    };
    let num = |t: &str| {
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("'{t}' is not a finite number"))
    };
    Ok([num(x)?, num(y)?, num(z)?])
}

/// Parses LEFT,RIGHT view indices.
pub fn parse_pair(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected LEFT,RIGHT view indices, got '{s}'"))?;
    let idx = |t: &str| {
        t.trim()
            .parse::<usize>()
            .map_err(|_| format!("'{t}' is not a view index"))
    };
    Ok((idx(a)?, idx(b)?))
}

/// Parses WIDTHxHEIGHT with each side in `min..=max`.
pub fn parse_size(s: &str, min: u32, max: u32) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got '{s}'"))?;
    let num = |t: &str| {
        t.parse::<u32>()
            .ok()
            .filter(|v| (min..=max).contains(v))
            .ok_or_else(|| match max {
                u32::MAX => format!("'{t}' is not a size of at least {min}"),
                _ => format!("'{t}' is not a size in {min}..={max}"),
            })
    };
    Ok((num(w)?, num(h)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_keywords_and_files() {
        assert_eq!("auto".parse(), Ok(DepthInput::Estimate(DepthSource::Auto)));
        assert_eq!(
            "embedded".parse(),
            Ok(DepthInput::Estimate(DepthSource::Embedded))
        );
        assert_eq!("./auto".parse(), Ok(DepthInput::File("./auto".into())));
        assert!(parse_depth_precision("fp16").is_err());
        assert_eq!(parse_depth_precision("int8"), Ok(Precision::Int8));
    }

    #[derive(clap::Parser)]
    struct Shared {
        #[command(flatten)]
        reshade: ReshadeArgs,
        #[command(flatten)]
        estimate: EstimateArgs,
        #[command(flatten)]
        relocate: RelocateArgs,
    }

    #[test]
    fn the_flags_defaults_are_the_library_s() {
        let cli = <Shared as clap::Parser>::try_parse_from(["reshader"]).unwrap();
        assert_eq!(cli.reshade.config(), ReshadeConfig::default());
        assert_eq!(cli.estimate.config(), DepthConfig::default());
        assert_eq!(cli.relocate.config(), RelocateConfig::default());
    }

    #[test]
    fn library_types_are_chosen_by_their_keywords() {
        let cli = <Shared as clap::Parser>::try_parse_from([
            "reshader",
            "--head",
            "lobes",
            "--relocate",
            "mesh",
            "--border",
            "inpaint",
        ])
        .unwrap();
        assert_eq!(cli.reshade.head, Some(Head::Lobes));
        assert_eq!(cli.relocate.kind, RelocateKind::Mesh);
        assert_eq!(cli.relocate.border, Border::Inpaint);
        let err = <Shared as clap::Parser>::try_parse_from(["reshader", "--head", "lobe"])
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("residual") && err.contains("lobes"), "{err}");
    }

    #[test]
    fn sizes_within_bounds() {
        assert_eq!(parse_size("640x480", 1, 8192), Ok((640, 480)));
        assert!(parse_size("640", 1, 8192).is_err());
        assert!(parse_size("0x480", 1, 8192).is_err());
        assert!(parse_size("99999x480", 1, 8192).is_err());
        assert_eq!(parse_size("4000x3000", 32, u32::MAX), Ok((4000, 3000)));
        assert_eq!(
            parse_size("8x8", 32, u32::MAX),
            Err("'8' is not a size of at least 32".into())
        );
    }
}
