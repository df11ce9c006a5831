//! `reshader live`: camera → working resolution → views → weave → display, one frame at a
//! time, dropping frames rather than queueing them.
//!
//! Capture (with decoding) runs on its own thread and leaves only its newest frame in a
//! one-slot mailbox; the processing loop always takes the newest, so a slow stage costs
//! frame rate, never latency.
//!
//! With `--depth network` the depth network runs on the working frame and each view is
//! relocated with that depth; a depth map is reused for later frames while it is younger
//! than `--depth-max-age-ms`, since the network is the slowest stage and the scene in
//! front of a fixed camera changes slowly.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use image::imageops::{self, FilterType};
use image::RgbImage;
use interleave::{Board, Weaver};

use super::{CameraRequest, CaptureError, Frame, FrameSource, PixelFormat};
use crate::depth::net::cli::EstimateArgs;
use crate::depth::net::{self as depth_net, DepthNet, DepthNetError, DepthSource, StageOptions};
use crate::depth::DepthMap;
use crate::device::display::{DisplayError, FrameSink};
use crate::io::photo::SrgbImage;
use crate::relocate::{self, RelocateArgs, RelocateError, Relocator};
use crate::reshade::net::cli::ReshadeArgs;
use crate::reshade::net::NetError;
use crate::reshade::{ReshadeError, Reshader, TrainingFrame};
use crate::views::{robust_focus, robust_range, Intrinsics, ViewCamera, ViewError, ViewRig};

#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(transparent)]
    Display(#[from] DisplayError),
    #[error(transparent)]
    Board(#[from] interleave::BoardError),
    #[error("weaving failed: {0}")]
    Weave(#[from] interleave::WeaveError),
    #[error("--board is required unless --list-formats is given")]
    NoBoard,
    #[error("cannot install the SIGINT/SIGTERM handler: {0}")]
    Signal(std::io::Error),
    #[error(transparent)]
    DepthNet(#[from] DepthNetError),
    #[error(transparent)]
    View(#[from] ViewError),
    #[error(transparent)]
    Relocate(#[from] RelocateError),
    #[error(transparent)]
    ReshadeNet(#[from] NetError),
    #[error(transparent)]
    Reshade(#[from] ReshadeError),
    #[error(transparent)]
    Memory(#[from] crate::pipeline::preflight::OverBudget),
    #[error("{0}")]
    Options(String),
}

/// Where the views' depth comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LiveDepthMode {
    /// No depth: every view is the camera frame (the panel shows it flat).
    Off,
    /// The depth network on the working frame; each view is relocated with it.
    Network,
}

#[derive(clap::Args, Debug)]
pub struct LiveArgs {
    /// V4L2 camera device, or a recording of raw YUYV/MJPEG frames (RSHFRM01 file).
    #[arg(long, default_value = "/dev/video0")]
    pub camera: PathBuf,
    /// Built-in board name (see `reshader boards`) or path of a board .toml file.
    #[arg(long, required_unless_present = "list_formats")]
    pub board: Option<String>,
    /// Per-unit calibration in Looking-Glass visual.json form.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Frame rate asked of the camera.
    #[arg(long, default_value_t = 30)]
    pub fps: u32,
    /// Where frames go: `none` (numbered PNGs in --out), `png:DIR`, `fb:/dev/fb0`, or
    /// `fb:FILE:WIDTHxHEIGHT:FORMAT[:STRIDE]` for a file standing in for a framebuffer.
    #[arg(long, default_value = "none")]
    pub display: String,
    /// Directory of the PNG frames for `--display none`.
    #[arg(long, default_value = "live-frames")]
    pub out: PathBuf,
    /// List the camera's formats, sizes and frame rates, and exit.
    #[arg(long)]
    pub list_formats: bool,
    /// Camera pixel format [default: the camera's current one if decodable, else MJPEG].
    #[arg(long)]
    pub format: Option<PixelFormat>,
    /// Capture size WIDTHxHEIGHT [default: the camera's current one].
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Working resolution of the views, WIDTHxHEIGHT [default: the board's view size].
    #[arg(long, value_parser = parse_size)]
    pub work_size: Option<(u32, u32)>,
    /// Stop after this many frames have been shown.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Replay a recording at its recorded pace (dropping frames when behind) instead of
    /// as fast as the pipeline takes them.
    #[arg(long)]
    pub realtime: bool,
    /// Depth for the views: off (flat: every view is the camera frame) or network.
    #[arg(long, value_enum, default_value_t = LiveDepthMode::Off)]
    pub depth: LiveDepthMode,
    /// Reuse a frame's depth for later frames until it is this many milliseconds old
    /// (0: run the depth network on every frame).
    #[arg(long, default_value_t = 500)]
    pub depth_max_age_ms: u64,
    /// Horizontal field of view of the camera in degrees, for relocating the views.
    #[arg(long, default_value_t = crate::io::photo::DEFAULT_HFOV_DEG)]
    pub fov: f64,
    #[command(flatten)]
    pub relocate: RelocateArgs,
    #[command(flatten)]
    pub estimate: EstimateArgs,
    #[command(flatten)]
    pub reshade: ReshadeArgs,
}

pub const LIVE_ABOUT: &str = "\
Show a live camera on a light-field panel: capture (V4L2, YUYV or MJPEG) → views at the
working resolution → weave for the board → display. Frames are dropped, never queued,
when a stage is slower than the camera. At -v the achieved fps and per-stage times are
logged once a second; a summary is printed at the end.

By default (--depth off) all views are the camera frame itself (the panel shows it flat).
With --depth network the depth network runs on the working frame (its depth reused while
younger than --depth-max-age-ms) and every view is relocated with it (--relocate).

Live views keep the camera's shading unless a reshading model is named (--model, or
$RESHADER_MODEL; needs --depth network): unlike render, live does not fall back to
models/reshade, because the shipped network takes about 0.1 s per view on a CPU, seconds
per frame for a 48-view board. --key-views and --reshade-scale cut that cost.

Examples:
  reshader live --camera /dev/video0 --list-formats
  reshader live --camera /dev/video0 --board looking-glass-portrait --display fb:/dev/fb0 -v
  reshader live --camera /dev/video0 --board looking-glass-portrait --depth network \\
      --work-size 210x280 --depth-max-age-ms 1000 -v
  reshader live --camera recording.rshfrm --board looking-glass-portrait --frames 300 -v";

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got '{s}'"))?;
    let num = |t: &str| {
        t.parse::<u32>()
            .ok()
            .filter(|&v| (1..=super::MAX_FRAME_SIDE).contains(&v))
            .ok_or_else(|| format!("'{t}' is not a size in 1..={}", super::MAX_FRAME_SIDE))
    };
    Ok((num(w)?, num(h)?))
}

/// `reshader live`.
pub fn run_live(args: &LiveArgs) -> Result<(), LiveError> {
    if args.list_formats {
        for format in super::list_formats(&args.camera)? {
            print!("{format}");
        }
        return Ok(());
    }
    let board_name = args.board.as_deref().ok_or(LiveError::NoBoard)?;
    let board = crate::pipeline::load_board(board_name, args.calibration.as_deref())?;
    // Before the networks load: the frame size asked for (--size), else no larger
    // than the views; once the camera says what it delivers, again with that.
    let work = args.work_size.unwrap_or_else(|| board.view_size());
    let asked = args.size.unwrap_or(work);
    check_memory(args, &board, asked)?;
    let depth = live_depth(args)?;
    let request = CameraRequest {
        format: args.format,
        size: args.size,
        fps: Some(args.fps),
        paced: args.realtime,
    };
    let source = super::open_source(&args.camera, &request)?;
    if source.size() != asked {
        check_memory(args, &board, source.size())?;
    }
    let sink = crate::device::display::open_sink(&args.display, &args.out)?;
    let stop = crate::device::gallery::cli::stop_on_signals().map_err(LiveError::Signal)?;
    let opts = LiveOptions {
        work_size: args.work_size,
        max_frames: args.frames,
        depth,
    };
    let summary = run_pipeline(source, sink, &board, &opts, &stop)?;
    eprintln!("{summary}");
    if summary.fps() < f64::from(args.fps) * 0.9 && summary.frames > 1 {
        eprintln!(
            "note: below the requested {} fps; a smaller --work-size or a board with fewer \
             panel pixels is faster",
            args.fps
        );
    }
    Ok(())
}

/// Refuses a live run whose frames of `frame` pixels would not fit --max-memory: the
/// estimate of rendering one such photo for the board at the working size, with the
/// networks live loads, the panel and no quilt.
fn check_memory(args: &LiveArgs, board: &Board, frame: (u32, u32)) -> Result<(), LiveError> {
    let work = args.work_size.unwrap_or_else(|| board.view_size());
    let (pw, ph) = board.panel_size();
    let depth = args.depth == LiveDepthMode::Network;
    let reshading = depth && named_reshade_model(&args.reshade).is_some();
    let size = crate::pipeline::preflight::RenderSize {
        photo: frame,
        views: board.views() as u32,
        view: work,
        quilt_pixels: 0,
        panel_pixels: u64::from(pw) * u64::from(ph),
        table_bytes: board.filter().table_bytes_per_subpixel(),
        network: reshading.then_some((
            args.reshade.reshade_scale,
            crate::pipeline::preflight::views_at_once(&args.reshade),
        )),
        depth_network: depth,
    };
    crate::pipeline::preflight::check_memory(
        format!(
            "showing {}x{} frames on {} ({} views of {}x{})",
            frame.0,
            frame.1,
            board.name(),
            board.views(),
            work.0,
            work.1
        ),
        &crate::pipeline::preflight::estimate(&size),
        " (or use a smaller --work-size or --size)",
    )?;
    Ok(())
}

/// The reshading model named by --model or $RESHADER_MODEL, unless it is `none`.
fn named_reshade_model(args: &ReshadeArgs) -> Option<PathBuf> {
    args.model
        .clone()
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
        .filter(|model| model.as_os_str() != "none")
}

/// The depth stage of `--depth network`, loaded before capture starts so that a bad model
/// fails before the camera is opened.
fn live_depth(args: &LiveArgs) -> Result<Option<LiveDepth>, LiveError> {
    if args.depth == LiveDepthMode::Off {
        if args
            .reshade
            .model
            .as_ref()
            .is_some_and(|m| m.as_os_str() != "none")
        {
            return Err(LiveError::Options(
                "--model needs --depth network: reshading needs the frame's depth".into(),
            ));
        }
        return Ok(None);
    }
    if !(args.fov > 0.0 && args.fov < 180.0) {
        return Err(LiveError::Options(format!(
            "--fov {} must be between 0 and 180 degrees",
            args.fov
        )));
    }
    let estimator = args
        .estimate
        .estimator(DepthSource::Network)
        .map_err(LiveError::Options)?;
    let reshader = live_reshader(&args.reshade)?;
    Ok(Some(LiveDepth {
        reshader,
        net: estimator.net()?,
        opts: *estimator.options(),
        max_age: Duration::from_millis(args.depth_max_age_ms),
        relocator: args.relocate.build(),
        hfov_deg: args.fov,
    }))
}

/// The reshading network when one is named explicitly (see [`LIVE_ABOUT`] for why live
/// has no default model), built before the camera opens so that a bad model fails first.
fn live_reshader(args: &ReshadeArgs) -> Result<Option<Box<dyn Reshader + Send + Sync>>, LiveError> {
    match named_reshade_model(args) {
        Some(_) => Ok(Some(args.build()?)),
        None => Ok(None),
    }
}

#[derive(Default)]
pub struct LiveOptions {
    pub work_size: Option<(u32, u32)>,
    pub max_frames: Option<u64>,
    /// None: flat views.
    pub depth: Option<LiveDepth>,
}

/// Depth and relocation of live frames.
pub struct LiveDepth {
    pub net: Arc<DepthNet>,
    pub opts: StageOptions,
    /// A depth map younger than this is reused for the next frame.
    pub max_age: Duration,
    pub relocator: Box<dyn Relocator>,
    pub hfov_deg: f64,
    /// None: the views keep the camera's shading.
    pub reshader: Option<Box<dyn Reshader + Send + Sync>>,
}

/// Stage names in pipeline order, as reported.
pub const STAGES: [&str; 6] = ["capture", "resize", "depth", "views", "weave", "display"];

/// What a run achieved.
#[derive(Clone, Debug, Default)]
pub struct LiveSummary {
    pub frames: u64,
    /// Frames the camera (or recording) delivered that were never shown.
    pub dropped: u64,
    /// Frames whose bytes could not be decoded.
    pub bad_frames: u64,
    /// Frames the depth network ran on (the others reused a fresh depth map).
    pub depth_runs: u64,
    pub elapsed: Duration,
    pub work_size: (u32, u32),
    pub panel_size: (u32, u32),
    /// Total time per stage, in [`STAGES`] order.
    pub stage_time: [Duration; 6],
}

impl LiveSummary {
    pub fn fps(&self) -> f64 {
        if self.elapsed.is_zero() {
            return 0.0;
        }
        self.frames as f64 / self.elapsed.as_secs_f64()
    }

    pub fn mean_stage_ms(&self) -> [f64; 6] {
        let n = self.frames.max(1) as f64;
        self.stage_time.map(|t| t.as_secs_f64() * 1e3 / n)
    }

    fn stages_line(&self) -> String {
        STAGES
            .iter()
            .zip(self.mean_stage_ms())
            .map(|(s, ms)| format!("{s} {ms:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl std::fmt::Display for LiveSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "live: {} frames in {:.2} s = {:.1} fps ({} dropped, {} undecodable, depth \
             estimated on {}); views {}x{}, panel {}x{}; mean ms per frame: {}",
            self.frames,
            self.elapsed.as_secs_f64(),
            self.fps(),
            self.dropped,
            self.bad_frames,
            self.depth_runs,
            self.work_size.0,
            self.work_size.1,
            self.panel_size.0,
            self.panel_size.1,
            self.stages_line()
        )
    }
}

/// Runs until the source ends, `max_frames` were shown, or `stop` is set.
pub fn run_pipeline(
    source: Box<dyn FrameSource>,
    mut sink: Box<dyn FrameSink>,
    board: &Board,
    opts: &LiveOptions,
    stop: &Arc<AtomicBool>,
) -> Result<LiveSummary, LiveError> {
    let work_size = opts.work_size.unwrap_or_else(|| board.view_size());
    log::info!("live: source {}", source.describe());
    log::info!("live: display {}", sink.describe());
    let depth_note = match &opts.depth {
        Some(d) => format!(
            "depth {} (reused for {} ms), reshading {}, relocation {}",
            d.net.manifest().name,
            d.max_age.as_millis(),
            d.reshader
                .as_ref()
                .map_or_else(|| "off".into(), |r| r.description()),
            d.relocator.description()
        ),
        None => "no depth (--depth off), so every view is the camera frame".into(),
    };
    log::info!(
        "live: {} views of {}x{} woven for {} ({}x{}); {depth_note}",
        board.views(),
        work_size.0,
        work_size.1,
        board.name(),
        board.width(),
        board.height()
    );
    let weaver = Weaver::new(board, work_size.0, work_size.1);
    let mailbox = Arc::new(Mailbox::default());
    let capture = spawn_capture(source, Arc::clone(&mailbox), Arc::clone(stop));
    let mut run = Run::new(work_size, weaver.panel_size());
    run.depth = opts.depth.as_ref().map(|d| DepthState {
        live: d,
        cone: f64::from(board.view_cone_deg()),
        latest: None,
    });
    let mut panel = RgbImage::new(0, 0);
    let result = loop {
        if stop.load(Ordering::SeqCst) || opts.max_frames.is_some_and(|m| run.total.frames >= m) {
            break Ok(());
        }
        let Some(next) = mailbox.take(stop) else {
            break Ok(());
        };
        let frame = match next {
            Ok(frame) => frame,
            Err(e) => break Err(e),
        };
        if let Err(e) = run.process(&frame, &weaver, &mut panel, sink.as_mut()) {
            break Err(e);
        }
    };
    stop.store(true, Ordering::SeqCst);
    let captured = capture.join().unwrap_or_default();
    run.total.dropped = captured.dropped + mailbox.overwritten();
    run.total.bad_frames = captured.bad_frames;
    run.total.elapsed = run.started.elapsed();
    result.map(|()| run.total)
}

/// The processing side's clock and counters.
struct Run<'a> {
    views: Vec<RgbImage>,
    depth: Option<DepthState<'a>>,
    started: Instant,
    total: LiveSummary,
    window: LiveSummary,
    window_start: Instant,
}

/// The depth stage's settings and the last depth map with its age.
struct DepthState<'a> {
    live: &'a LiveDepth,
    cone: f64,
    latest: Option<(DepthMap, Instant)>,
}

impl DepthState<'_> {
    /// Estimates depth for `work` unless the last map is still fresh; says whether it ran.
    fn refresh(&mut self, work: &RgbImage) -> Result<bool, LiveError> {
        let stale = self
            .latest
            .as_ref()
            .is_none_or(|(_, at)| at.elapsed() > self.live.max_age);
        if stale {
            let (map, _) = depth_net::network_depth(&self.live.net, work, &self.live.opts)?;
            self.latest = Some((map, Instant::now()));
        }
        Ok(stale)
    }
}

impl Run<'_> {
    fn new(work_size: (u32, u32), panel_size: (u32, u32)) -> Self {
        let total = LiveSummary {
            work_size,
            panel_size,
            ..LiveSummary::default()
        };
        Self {
            views: Vec::new(),
            depth: None,
            started: Instant::now(),
            window: total.clone(),
            total,
            window_start: Instant::now(),
        }
    }

    fn process(
        &mut self,
        frame: &Frame,
        weaver: &Weaver,
        panel: &mut RgbImage,
        sink: &mut dyn FrameSink,
    ) -> Result<(), LiveError> {
        let (w, h) = self.total.work_size;
        let mut times = [Duration::ZERO; 6];
        times[0] = frame.decode_time;
        let t = Instant::now();
        let work = cover_resize(&frame.image, w, h);
        times[1] = t.elapsed();
        let mut estimated = false;
        match self.depth.as_mut() {
            Some(state) => {
                let t = Instant::now();
                estimated = state.refresh(&work)?;
                times[2] = t.elapsed();
                let t = Instant::now();
                self.views = relocated_views(&work, state, weaver.views())?;
                times[3] = t.elapsed();
            }
            None => {
                let t = Instant::now();
                flat_views(&work, weaver.views(), &mut self.views);
                times[3] = t.elapsed();
            }
        }
        let t = Instant::now();
        weaver.weave_into(&self.views, panel)?;
        times[4] = t.elapsed();
        let t = Instant::now();
        sink.show(panel)?;
        times[5] = t.elapsed();
        for summary in [&mut self.total, &mut self.window] {
            summary.frames += 1;
            summary.depth_runs += u64::from(estimated);
            for (acc, t) in summary.stage_time.iter_mut().zip(times) {
                *acc += t;
            }
        }
        self.report_window();
        Ok(())
    }

    /// Logs the last second's rate and stage times.
    fn report_window(&mut self) {
        let elapsed = self.window_start.elapsed();
        if elapsed < Duration::from_secs(1) {
            return;
        }
        self.window.elapsed = elapsed;
        log::info!(
            "live: {:.1} fps; mean ms: {}",
            self.window.fps(),
            self.window.stages_line()
        );
        self.window = LiveSummary {
            work_size: self.total.work_size,
            panel_size: self.total.panel_size,
            ..LiveSummary::default()
        };
        self.window_start = Instant::now();
    }
}

/// The views for one frame, into buffers reused between frames. Without depth every
/// camera sees the same picture; this is where depth estimation and per-view reshading
/// and relocation go.
fn flat_views(work: &RgbImage, count: usize, views: &mut Vec<RgbImage>) {
    views.resize_with(count, || RgbImage::new(work.width(), work.height()));
    for view in views.iter_mut() {
        if view.dimensions() == work.dimensions() {
            view.copy_from_slice(work);
        } else {
            *view = work.clone();
        }
    }
}

/// The views of one frame seen from the board's cameras, reshaded (with a model) and
/// relocated with its depth: the same rig as `render` (zero-parallax plane at the robust
/// middle depth, baseline fitted to the parallax budget), recomputed per frame because
/// the depth changes.
fn relocated_views(
    work: &RgbImage,
    state: &DepthState,
    count: usize,
) -> Result<Vec<RgbImage>, LiveError> {
    let (depth, _) = state
        .latest
        .as_ref()
        .expect("depth refreshed before the views");
    let image = SrgbImage::from_rgb8(work);
    let source = Intrinsics::from_hfov(work.width(), work.height(), state.live.hfov_deg);
    let reference = source.cover(work.width(), work.height());
    let focus = robust_focus(depth);
    let depthiness =
        ViewRig::fitting_depthiness(state.cone, focus, robust_range(depth), &reference);
    let cameras = ViewRig::new(count, state.cone, focus, depthiness)?.cameras(&reference);
    let reach = relocate::reach_of(cameras.iter().map(|c| c.centre), &source);
    let prepared = state
        .live
        .relocator
        .prepare(&image, depth, &source, reach)?;
    let reshaded = match &state.live.reshader {
        Some(reshader) => reshade_views(&**reshader, &image, depth, &source, focus, &cameras)?,
        None => Vec::new(),
    };
    cameras
        .iter()
        .enumerate()
        .map(|(i, camera)| {
            let colours = reshaded.get(i).unwrap_or(&image);
            Ok(prepared.render(colours, camera)?.to_rgb8())
        })
        .collect()
}

/// The frame reshaded for every camera, as `render` does: in the training frame, where
/// the focus depth is the training scenes'.
fn reshade_views(
    reshader: &dyn Reshader,
    image: &SrgbImage,
    depth: &DepthMap,
    source: &Intrinsics,
    focus: f64,
    cameras: &[ViewCamera],
) -> Result<Vec<SrgbImage>, LiveError> {
    let frame = TrainingFrame::for_focus(focus);
    let training_depth = frame.depth(depth);
    let prepared = reshader.prepare(image, &training_depth, source)?;
    let centres: Vec<[f64; 3]> = cameras.iter().map(|c| frame.camera(c.centre)).collect();
    Ok(prepared.reshade_all(&centres)?)
}

/// Scales `image` to cover `w`×`h` and crops the centre, keeping its aspect.
pub fn cover_resize(image: &RgbImage, w: u32, h: u32) -> RgbImage {
    let (iw, ih) = image.dimensions();
    if (iw, ih) == (w, h) {
        return image.clone();
    }
    // Crop first to the target aspect so the resize touches only the pixels kept.
    let (cw, ch) = if u64::from(iw) * u64::from(h) > u64::from(ih) * u64::from(w) {
        (
            ((u64::from(ih) * u64::from(w)) / u64::from(h)).max(1) as u32,
            ih,
        )
    } else {
        (
            iw,
            ((u64::from(iw) * u64::from(h)) / u64::from(w)).max(1) as u32,
        )
    };
    let cropped = imageops::crop_imm(image, (iw - cw) / 2, (ih - ch) / 2, cw, ch).to_image();
    imageops::resize(&cropped, w, h, FilterType::Triangle)
}

#[derive(Default)]
struct CaptureStats {
    dropped: u64,
    bad_frames: u64,
}

fn spawn_capture(
    mut source: Box<dyn FrameSource>,
    mailbox: Arc<Mailbox>,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<CaptureStats> {
    std::thread::spawn(move || {
        let mut stats = CaptureStats::default();
        let realtime = source.realtime();
        while !stop.load(Ordering::SeqCst) {
            match source.next_frame() {
                Ok(Some(frame)) if realtime => mailbox.put(frame),
                Ok(Some(frame)) => mailbox.put_when_empty(frame, &stop),
                Ok(None) => break,
                Err(e) if !e.is_fatal() => {
                    stats.bad_frames += 1;
                    log::warn!("{e}; skipping it");
                }
                Err(e) => {
                    mailbox.fail(e);
                    break;
                }
            }
        }
        mailbox.close();
        stats.dropped = source.dropped();
        stats
    })
}

/// A one-frame slot: a new frame replaces one not yet taken.
#[derive(Default)]
struct Mailbox {
    slot: Mutex<Slot>,
    ready: Condvar,
}

#[derive(Default)]
struct Slot {
    frame: Option<Frame>,
    error: Option<CaptureError>,
    closed: bool,
    overwritten: u64,
}

impl Mailbox {
    fn put(&self, frame: Frame) {
        let mut slot = self.slot.lock().expect("capture mailbox poisoned");
        if slot.frame.replace(frame).is_some() {
            slot.overwritten += 1;
        }
        self.ready.notify_all();
    }

    /// For sources that are not real time: waits until the previous frame was taken.
    fn put_when_empty(&self, frame: Frame, stop: &AtomicBool) {
        let mut slot = self.slot.lock().expect("capture mailbox poisoned");
        while slot.frame.is_some() && !stop.load(Ordering::SeqCst) {
            slot = self
                .ready
                .wait_timeout(slot, Duration::from_millis(100))
                .expect("capture mailbox poisoned")
                .0;
        }
        slot.frame = Some(frame);
        self.ready.notify_all();
    }

    fn fail(&self, error: CaptureError) {
        self.slot.lock().expect("capture mailbox poisoned").error = Some(error);
        self.ready.notify_all();
    }

    fn close(&self) {
        self.slot.lock().expect("capture mailbox poisoned").closed = true;
        self.ready.notify_all();
    }

    /// The newest frame, waiting for one; `None` once capture ended and the slot is
    /// empty, or when `stop` is set. A capture error is returned after the frames
    /// delivered before it.
    fn take(&self, stop: &AtomicBool) -> Option<Result<Frame, LiveError>> {
        let mut slot = self.slot.lock().expect("capture mailbox poisoned");
        loop {
            if let Some(frame) = slot.frame.take() {
                self.ready.notify_all();
                return Some(Ok(frame));
            }
            if let Some(error) = slot.error.take() {
                return Some(Err(error.into()));
            }
            if slot.closed || stop.load(Ordering::SeqCst) {
                return None;
            }
            slot = self
                .ready
                .wait_timeout(slot, Duration::from_millis(100))
                .expect("capture mailbox poisoned")
                .0;
        }
    }

    fn overwritten(&self) -> u64 {
        self.slot
            .lock()
            .expect("capture mailbox poisoned")
            .overwritten
    }
}

#[cfg(test)]
mod tests;
