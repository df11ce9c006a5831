//! The render flow, stage by stage: load → fit → reshade → relocate → weave → write.
//! Every input is read and validated before anything is written, and all files of a run
//! are staged and moved into place together.

pub mod preflight;
pub mod progress;
pub mod record;
pub mod rgbd;
pub mod sheet;
mod write;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use image::RgbImage;
use interleave::{Board, BoardError, WeaveError};

use crate::depth::holes::HolePolicy;
use crate::depth::net::{DepthEstimator, DepthNetError, StageReport};
use crate::depth::{DepthError, DepthKind, DepthMap, DepthReport};
use crate::io::output::{self, OutputError, Staging};
use crate::io::photo::{Photo, PhotoError, SrgbImage};
use crate::io::preview::PreviewError;
use crate::io::record::{FileRecord, Timings};
use crate::pipeline::progress::Progress;
use crate::relocate::{PreparedRelocation, RelocateError, Relocator};
use crate::reshade::{ReshadeError, Reshader, TrainingFrame, TRAINING_FOCUS, TRAINING_REACH};
use crate::views::{robust_focus, robust_range, Intrinsics, ViewCamera, ViewError, ViewRig};
use record::{
    DepthRecord, FileDepthRecord, Geometry, Inputs, PhotoRecord, RunRecord, Setting, Versions,
};

use write::{
    board_record, commit_with_record, file_record, view_records, weave, write_products, write_rgbd,
};

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Photo(#[from] PhotoError),
    #[error(transparent)]
    Depth(#[from] DepthError),
    #[error(transparent)]
    DepthNet(#[from] DepthNetError),
    #[error(transparent)]
    View(#[from] ViewError),
    #[error(transparent)]
    Relocate(#[from] RelocateError),
    #[error(transparent)]
    Reshade(#[from] ReshadeError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Board(#[from] BoardError),
    #[error(transparent)]
    Preview(#[from] PreviewError),
    #[error("weaving failed: {0}")]
    Weave(#[from] WeaveError),
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("view directory {dir}: {detail}")]
    ViewDir { dir: PathBuf, detail: String },
    #[error("--sbs-pair {left},{right}: the board has views 0..{}", views - 1)]
    SbsPair {
        left: usize,
        right: usize,
        views: usize,
    },
}

/// Which files `render` writes; run.json is always written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Product {
    Views,
    Quilt,
    Panel,
    Sbs,
    /// The photo beside its depth (`rgbd.png`), for RGB-D viewers.
    Rgbd,
    /// The views swept left to right and back (`preview.gif`).
    Preview,
    /// A page that shows the view under the pointer (`preview.html`).
    Html,
}

impl crate::io::keyword::Keyword for Product {
    const ALL: &'static [(Self, &'static str)] = &[
        (Self::Views, "views"),
        (Self::Quilt, "quilt"),
        (Self::Panel, "panel"),
        (Self::Sbs, "sbs"),
        (Self::Rgbd, "rgbd"),
        (Self::Preview, "preview"),
        (Self::Html, "html"),
    ];
}

/// Where a scene's depth comes from.
#[derive(Clone)]
pub enum SceneDepth {
    /// A depth file, read as `kind`, its holes treated as `holes` says.
    File {
        path: PathBuf,
        kind: DepthKind,
        holes: HolePolicy,
    },
    /// Embedded in the photo or from the depth network; shared so that a batch loads the
    /// network once.
    Estimate(Arc<DepthEstimator>),
}

/// What produced a scene's depth, for run.json.
pub enum DepthOrigin {
    File { path: PathBuf, report: DepthReport },
    Estimated(Box<StageReport>),
}

/// A photo with its depth.
pub struct Scene {
    pub photo: Photo,
    /// At the photo's resolution, or, when estimated for views of a known size, at the
    /// size the photo is fitted to for them (see [`Scene::load`]).
    pub depth: DepthMap,
    pub depth_origin: DepthOrigin,
}

/// Photo and depth resampled for views of a given size, with their cameras.
pub struct Fitted {
    pub image: SrgbImage,
    pub depth: DepthMap,
    /// The camera that took `image`.
    pub source: Intrinsics,
    /// The unmoved camera at the output size (the photo scaled to cover it, centred).
    pub reference: Intrinsics,
}

impl Fitted {
    /// `image` (taken with `hfov_deg`) and its depth shrunk to cover views of
    /// `width`×`height` when they have more pixels than such views can show; see
    /// [`Scene::fitted`].
    pub fn new(
        image: &SrgbImage,
        hfov_deg: f64,
        depth: &DepthMap,
        width: u32,
        height: u32,
    ) -> Fitted {
        let (fw, fh) = Self::size((image.width(), image.height()), (width, height));
        let source = Intrinsics::from_hfov(fw, fh, hfov_deg);
        Fitted {
            image: image.resized(fw, fh),
            depth: depth.resized(fw as usize, fh as usize),
            source,
            reference: source.cover(width, height),
        }
    }

    /// The size a photo of `photo` pixels is fitted to for views of `views`: scaled
    /// to just cover them when it is larger, else its own.
    pub fn size((pw, ph): (u32, u32), (width, height): (u32, u32)) -> (u32, u32) {
        let cover = (f64::from(width) / f64::from(pw)).max(f64::from(height) / f64::from(ph));
        if cover < 1.0 {
            (
                ((f64::from(pw) * cover).ceil() as u32).max(1),
                ((f64::from(ph) * cover).ceil() as u32).max(1),
            )
        } else {
            (pw, ph)
        }
    }
}

impl Scene {
    /// Loads the photo (timed as `load`) and its depth: a file (also `load`) or the
    /// estimator (`depth`, and `depth_model` when this call loads the network). With
    /// `views` (the size of the views the scene is for), estimated depth comes at the
    /// size [`Fitted`] fits the photo to: no work is spent on, and no memory held for,
    /// depth finer than the views can show.
    pub fn load(
        photo: &Path,
        depth: &SceneDepth,
        fov: Option<f64>,
        views: Option<(u32, u32)>,
        t: &mut Timings,
    ) -> Result<Self, PipelineError> {
        let photo_path = photo;
        let photo = t.time("load", || Photo::load(photo_path, fov))?;
        let (depth, depth_origin) = match depth {
            SceneDepth::File { path, kind, holes } => {
                let (map, report) =
                    t.time("load", || DepthMap::load(path, *kind, *holes, &photo.image))?;
                let origin = DepthOrigin::File {
                    path: path.clone(),
                    report,
                };
                (map, origin)
            }
            SceneDepth::Estimate(estimator) => {
                let rgb = photo.image.to_rgb8();
                let full = (rgb.width(), rgb.height());
                let (w, h) = views.map_or(full, |v| Fitted::size(full, v));
                let (map, report) =
                    estimator.depth(photo_path, &rgb, [w as usize, h as usize], t)?;
                (map, DepthOrigin::Estimated(Box::new(report)))
            }
        };
        Ok(Self {
            photo,
            depth,
            depth_origin,
        })
    }

    pub fn focus(&self, requested: Option<f64>) -> (f64, Setting) {
        focus_of(&self.depth, requested)
    }

    /// Shrinks the photo when it has more pixels than views of `width`×`height` can
    /// show (the mesh has one vertex per pixel); smaller photos are kept and magnified
    /// by the rasteriser.
    pub fn fitted(&self, width: u32, height: u32) -> Fitted {
        Fitted::new(
            &self.photo.image,
            self.photo.hfov_deg,
            &self.depth,
            width,
            height,
        )
    }

    fn inputs(&self) -> Result<Inputs, PipelineError> {
        let record = |path: &Path| {
            FileRecord::of(path).map_err(|source| PipelineError::Io {
                path: path.into(),
                source,
            })
        };
        Ok(Inputs {
            photo: PhotoRecord {
                file: record(&self.photo.path)?,
                size: [self.photo.image.width(), self.photo.image.height()],
                hfov_deg: self.photo.hfov_deg,
                fov_source: self.photo.fov_source,
            },
            depth: match &self.depth_origin {
                DepthOrigin::File { path, report } => DepthRecord::File(FileDepthRecord {
                    source: "file",
                    file: record(path)?,
                    report: report.clone(),
                }),
                DepthOrigin::Estimated(report) => DepthRecord::Estimated((**report).clone()),
            },
            board_file: None,
            calibration: None,
        })
    }
}

/// A board by built-in name or file, with an optional per-unit calibration applied.
pub fn load_board(name_or_path: &str, calibration: Option<&Path>) -> Result<Board, BoardError> {
    let mut board = Board::resolve(name_or_path)?;
    if let Some(cal) = calibration {
        board.apply_calibration_file(cal)?;
    }
    Ok(board)
}

pub struct RenderOptions {
    pub photo: PathBuf,
    pub depth: SceneDepth,
    pub fov: Option<f64>,
    pub board: Board,
    pub board_file: Option<PathBuf>,
    pub calibration: Option<PathBuf>,
    pub focus: Option<f64>,
    /// `None`: fit the parallax budget (see [`ViewRig::fitting_depthiness`]).
    pub depthiness: Option<f64>,
    /// The reshading cameras' baseline; `None`: see [`BoardRig::new`].
    pub shading_depthiness: Option<f64>,
    /// Empty means everything.
    pub only: Vec<Product>,
    pub sbs_pair: Option<(usize, usize)>,
    pub out_dir: PathBuf,
    /// A bar over the views, on a terminal (hidden in batches, which count photos).
    pub progress: Progress,
}

impl RenderOptions {
    fn wants(&self, product: Product) -> bool {
        self.only.is_empty() || self.only.contains(&product)
    }

    fn sbs_pair(&self) -> Result<(usize, usize), PipelineError> {
        let n = self.board.views();
        let (left, right) = self.sbs_pair.unwrap_or((0, n - 1));
        if left >= n || right >= n {
            return Err(PipelineError::SbsPair {
                left,
                right,
                views: n,
            });
        }
        Ok((left, right))
    }
}

/// Renders every view of the board and writes the requested products plus run.json
/// into `opts.out_dir`.
pub fn render(
    opts: &RenderOptions,
    reshader: &dyn Reshader,
    relocator: &dyn Relocator,
) -> Result<RunRecord, PipelineError> {
    let mut t = Timings::default();
    let sbs_pair = opts.sbs_pair()?;
    let board = &opts.board;
    let progress = &opts.progress;
    progress.set_message("depth");
    let (vw, vh) = board.view_size();
    let scene = Scene::load(&opts.photo, &opts.depth, opts.fov, Some((vw, vh)), &mut t)?;
    let fitted = t.time("fit", || scene.fitted(vw, vh));
    let BoardRig {
        rig,
        focus_source,
        depthiness_source,
        shading,
        shading_source,
    } = BoardRig::new(
        board,
        (&scene.depth, &fitted.reference),
        (opts.focus, opts.depthiness),
        opts.shading_depthiness,
    )?;
    let (focus, depthiness) = (rig.focus, rig.depthiness);
    let cameras = rig.cameras(&fitted.reference);
    let shading_centres = shading.centres();
    let frame = TrainingFrame::for_focus(focus);
    let mut inputs = scene.inputs()?;
    // Everything past here works at the views' size: the photo and its depth at full
    // resolution would be a third of a 12-megapixel render's peak memory.
    drop(scene);
    let views = render_views(
        &fitted,
        (&cameras, &shading_centres),
        frame,
        Some(reshader),
        relocator,
        progress,
        &mut t,
    )?;

    progress.set_message("writing");
    let mut staging = Staging::new(&opts.out_dir)?;
    write_products(opts, &views, sbs_pair, &mut staging, &mut t)?;
    let rgbd = if opts.wants(Product::Rgbd) {
        Some(write_rgbd(
            &fitted,
            focus,
            depthiness,
            &mut staging,
            &mut t,
        )?)
    } else {
        None
    };
    inputs.board_file = file_record(opts.board_file.as_deref())?;
    inputs.calibration = file_record(opts.calibration.as_deref())?;
    let record = RunRecord {
        command: "render".into(),
        inputs,
        board: Some(board_record(board)),
        geometry: Geometry {
            units: "depth map units",
            focus,
            focus_source,
            depthiness_source,
            rig: Some(rig),
            shading_depthiness: Some(shading.depthiness),
            shading_depthiness_source: Some(shading_source),
            training_scale: frame.scale,
        },
        views: view_records(&cameras, &shading_centres, &fitted.reference),
        reshade: reshader.description(),
        relocate: relocator.description(),
        blend: Some(opts.board.filter().blend.name().into()),
        rgbd,
        outputs: Vec::new(),
        timings_ms: t,
        versions: Versions::default(),
    };
    let record = commit_with_record(staging, record);
    progress.finish();
    record
}

/// The zero-parallax depth: the one requested, else the depth's robust middle.
pub fn focus_of(depth: &DepthMap, requested: Option<f64>) -> (f64, Setting) {
    match requested {
        Some(f) => (f, Setting::CommandLine),
        None => (robust_focus(depth), Setting::RobustMiddleDepth),
    }
}

/// A board's view rig for a scene, as `render` chooses it: the zero-parallax depth and
/// the depthiness given, else the robust middle depth and the parallax budget's; and the
/// cameras each view is reshaded for.
///
/// The two rigs differ because they answer different questions. The views' baseline is
/// cut so that one photo's parallax stays believable (3 % of the view width), often to a
/// few percent of the view cone. A viewer still moves across the whole cone, and a
/// highlight moves with the angle it is seen from, so each view is reshaded for a camera
/// on a wider baseline: the given shading depthiness, else the widest (at most the view
/// cone) whose outermost cameras stay within [`TRAINING_REACH`] of the photo in the
/// network's units, and never narrower than the views' own.
pub struct BoardRig {
    pub rig: ViewRig,
    pub focus_source: Setting,
    pub depthiness_source: Setting,
    pub shading: ViewRig,
    pub shading_source: Setting,
}

impl BoardRig {
    /// The rigs of `board`'s views for a scene of `depth` (at the photo's resolution)
    /// seen through `reference`, the unmoved camera at the views' size.
    pub fn new(
        board: &Board,
        (depth, reference): (&DepthMap, &Intrinsics),
        focus_depthiness: (Option<f64>, Option<f64>),
        shading_depthiness: Option<f64>,
    ) -> Result<Self, ViewError> {
        let cone = f64::from(board.view_cone_deg());
        let views = (board.views(), cone);
        Self::for_views(
            views,
            (depth, reference),
            focus_depthiness,
            shading_depthiness,
        )
    }

    /// The rigs of `views` views over a cone of `cone` degrees (`live` has no board file
    /// behind its frames, only the count and the cone).
    pub fn for_views(
        (views, cone): (usize, f64),
        (depth, reference): (&DepthMap, &Intrinsics),
        (focus, depthiness): (Option<f64>, Option<f64>),
        shading_depthiness: Option<f64>,
    ) -> Result<Self, ViewError> {
        let (focus, focus_source) = focus_of(depth, focus);
        let (depthiness, depthiness_source) = match depthiness {
            Some(d) => (d, Setting::CommandLine),
            None => (
                ViewRig::fitting_depthiness(cone, focus, robust_range(depth), reference),
                Setting::ParallaxBudget,
            ),
        };
        let (shading, shading_source) = match shading_depthiness {
            Some(d) => (d, Setting::CommandLine),
            None => (
                reach_depthiness(cone).max(depthiness),
                Setting::TrainingReach,
            ),
        };
        Ok(Self {
            rig: ViewRig::new(views, cone, focus, depthiness)?,
            focus_source,
            depthiness_source,
            shading: ViewRig::new(views, cone, focus, shading)?,
            shading_source,
        })
    }
}

/// The depthiness (at most 1) whose outermost cameras stand [`TRAINING_REACH`] from the
/// photo's in the network's units, where the focus lies at [`TRAINING_FOCUS`].
fn reach_depthiness(cone_deg: f64) -> f64 {
    let full = TRAINING_FOCUS * (cone_deg.to_radians() / 2.0).tan();
    if full > 0.0 {
        (TRAINING_REACH / full).min(1.0)
    } else {
        1.0
    }
}

/// Each view's colours reshaded for its shading camera (centres in depth-map units; the
/// images still in the input camera's frame, in view order), and the relocation prepared
/// for the views' `cameras`.
pub fn reshade_views<'a>(
    fitted: &Fitted,
    (cameras, shading): (&[ViewCamera], &[[f64; 3]]),
    frame: TrainingFrame,
    reshader: &dyn Reshader,
    relocator: &'a dyn Relocator,
    t: &mut Timings,
) -> Result<(Vec<SrgbImage>, Box<dyn PreparedRelocation + 'a>), PipelineError> {
    let training_depth = frame.depth(&fitted.depth);
    let prepared = t.time("reshade_prepare", || {
        reshader.prepare(&fitted.image, &training_depth, &fitted.source)
    })?;
    let relocation = prepare_relocation(fitted, cameras, relocator, t)?;
    let centres: Vec<[f64; 3]> = shading.iter().map(|&c| frame.camera(c)).collect();
    let reshaded = t.time("reshade", || prepared.reshade_all(&centres))?;
    Ok((reshaded, relocation))
}

/// The relocation of `fitted` prepared once for the views' `cameras`.
fn prepare_relocation<'a>(
    fitted: &Fitted,
    cameras: &[ViewCamera],
    relocator: &'a dyn Relocator,
    t: &mut Timings,
) -> Result<Box<dyn PreparedRelocation + 'a>, RelocateError> {
    t.time("relocate_prepare", || {
        relocator.prepare(&fitted.image, &fitted.depth, &fitted.source, cameras)
    })
}

/// Every view: the photo reshaded for its shading camera (unless `reshader` is `None`,
/// when the views keep the photo's colours), relocated to its camera. The views are
/// reshaded as they are relocated, one per core at a time, so that only that many
/// reshaded images are held, not one per view.
pub fn render_views(
    fitted: &Fitted,
    (cameras, shading): (&[ViewCamera], &[[f64; 3]]),
    frame: TrainingFrame,
    reshader: Option<&dyn Reshader>,
    relocator: &dyn Relocator,
    progress: &Progress,
    t: &mut Timings,
) -> Result<Vec<RgbImage>, PipelineError> {
    progress.set_message(if reshader.is_some() {
        "reshading and relocating"
    } else {
        "relocating"
    });
    let training_depth = frame.depth(&fitted.depth);
    let prepared = match reshader {
        Some(r) => Some(t.time("reshade_prepare", || {
            r.prepare(&fitted.image, &training_depth, &fitted.source)
        })?),
        None => None,
    };
    let relocation = prepare_relocation(fitted, cameras, relocator, t)?;
    let centres: Vec<[f64; 3]> = shading.iter().map(|&c| frame.camera(c)).collect();
    let mut reshaded = prepared.as_ref().map(|p| p.reshade_each(&centres));
    let threads = crate::parallel::cores();
    let mut views = Vec::with_capacity(cameras.len());
    while views.len() < cameras.len() {
        let first = views.len();
        let count = threads.min(cameras.len() - first);
        let colours: Vec<SrgbImage> = match &mut reshaded {
            Some(stream) => t.time("reshade", || {
                stream
                    .by_ref()
                    .take(count)
                    .collect::<Result<_, ReshadeError>>()
            })?,
            None => Vec::new(),
        };
        let relocated = t.time("relocate", || {
            crate::parallel::map(count, threads, |i| {
                let colours = colours.get(i).unwrap_or(&fitted.image);
                let view = relocation.render_rgb8(colours, &cameras[first + i])?;
                progress.inc(1);
                Ok::<_, RelocateError>(view)
            })
        })?;
        views.extend(relocated);
    }
    log::info!("rendered {} views", views.len());
    Ok(views)
}

/// Settings shared by the single-view stage commands.
pub struct ViewRequest<'a> {
    pub scene: &'a Scene,
    pub camera: [f64; 3],
    pub focus: Option<f64>,
}

/// The photo reshaded for `camera`, still in the input camera's frame.
pub fn reshade_photo(
    req: &ViewRequest,
    reshader: &dyn Reshader,
) -> Result<SrgbImage, PipelineError> {
    let (focus, _) = req.scene.focus(req.focus);
    let frame = TrainingFrame::for_focus(focus);
    let training_depth = frame.depth(&req.scene.depth);
    let image = &req.scene.photo.image;
    let camera = Intrinsics::from_hfov(image.width(), image.height(), req.scene.photo.hfov_deg);
    let prepared = reshader.prepare(image, &training_depth, &camera)?;
    Ok(prepared.reshade(frame.camera(req.camera))?)
}

/// The novel view from `camera` at the photo's resolution, with the zero-parallax plane
/// as in `render`, so that it matches the render's view for the same camera offset.
pub fn render_view(
    req: &ViewRequest,
    reshader: Option<&dyn Reshader>,
    relocator: &dyn Relocator,
) -> Result<SrgbImage, PipelineError> {
    let scene = req.scene;
    let (focus, _) = scene.focus(req.focus);
    let source = Intrinsics::from_hfov(
        scene.photo.image.width(),
        scene.photo.image.height(),
        scene.photo.hfov_deg,
    );
    let camera = ViewCamera::off_axis(&source, req.camera, focus)?;
    let colours = match reshader {
        Some(r) => reshade_photo(req, r)?,
        None => scene.photo.image.clone(),
    };
    Ok(relocator.render(&colours, &scene.depth, &source, &camera)?)
}

/// Writes an image to `path` atomically, as PNG, EXR or npy by extension.
pub fn write_image(path: &Path, image: &SrgbImage) -> Result<(), PipelineError> {
    let format = output::FileFormat::require(path, output::IMAGE_FORMATS)?;
    let bytes = output::encode_image(path, image, format)?;
    Ok(output::write_atomic(path, &bytes)?)
}

/// Weaves the `view_NN.png` files of `dir` (exactly the board's view count, numbered
/// from 0 without gaps) into a panel frame.
pub fn weave_dir(dir: &Path, board: &Board) -> Result<RgbImage, PipelineError> {
    let views = read_view_dir(dir, board.views())?;
    let mut t = Timings::default();
    weave(board, &views, &mut t)
}

fn read_view_dir(dir: &Path, expected: usize) -> Result<Vec<RgbImage>, PipelineError> {
    let dir_err = |detail: String| PipelineError::ViewDir {
        dir: dir.into(),
        detail,
    };
    let entries = std::fs::read_dir(dir).map_err(|e| dir_err(e.to_string()))?;
    let mut indexed: Vec<(usize, PathBuf)> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let index = output::view_index(&name).filter(|_| name.ends_with(".png"))?;
            Some((index, e.path()))
        })
        .collect();
    indexed.sort();
    if indexed.len() != expected {
        return Err(dir_err(format!(
            "found {} view_NN.png files, the board has {expected} views",
            indexed.len()
        )));
    }
    if let Some(k) = indexed.iter().enumerate().position(|(k, (i, _))| *i != k) {
        return Err(dir_err(format!("view_{k:02}.png is missing")));
    }
    indexed
        .iter()
        .map(|(_, path)| Ok(crate::io::photo::load_rgb8(path)?))
        .collect()
}
