//! What `live` is asked to do, checked and loaded before the camera opens: a bad board,
//! model or memory ceiling fails before any frame is captured.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use interleave::Board;

use super::{run_pipeline, LiveDepth, LiveError, LiveOptions, LiveSummary};
use crate::depth::net::{DepthConfig, DepthSource};
use crate::device::capture::FrameSource;
use crate::device::capture::{CameraRequest, PixelFormat};
use crate::device::display::FrameSink;
use crate::relocate::RelocateConfig;
use crate::reshade::net::choice::ReshadeConfig;
use crate::reshade::Reshader;

/// Where the views' depth comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LiveDepthMode {
    /// No depth: every view is the camera frame (the panel shows it flat).
    #[default]
    Off,
    /// The depth network on the working frame; each view is relocated with it.
    Network,
}

impl crate::io::keyword::Keyword for LiveDepthMode {
    const ALL: &'static [(Self, &'static str)] = &[(Self::Off, "off"), (Self::Network, "network")];
}

/// A live run's settings.
#[derive(Clone, Debug)]
pub struct LiveConfig {
    /// A V4L2 device, or a recording (RSHFRM01 file).
    pub camera: PathBuf,
    /// Frame rate asked of the camera.
    pub fps: u32,
    /// `none`, `png:DIR`, `fb:/dev/fb0` or `fb:FILE:WIDTHxHEIGHT:FORMAT[:STRIDE]`.
    pub display: String,
    /// The PNG frames' folder for `display` `none`.
    pub out: PathBuf,
    /// `None`: the camera's current format if decodable, else MJPEG.
    pub format: Option<PixelFormat>,
    /// Capture size (`None`: the camera's current one).
    pub size: Option<(u32, u32)>,
    /// The views' working size (`None`: the board's view size).
    pub work_size: Option<(u32, u32)>,
    /// Stop after this many frames.
    pub frames: Option<u64>,
    /// Replay a recording at its recorded pace.
    pub realtime: bool,
    pub depth: LiveDepthMode,
    /// A depth map younger than this is reused.
    pub depth_max_age: Duration,
    /// The camera's horizontal field of view, degrees.
    pub fov: f64,
    pub relocate: RelocateConfig,
    pub depth_net: DepthConfig,
    pub reshade: ReshadeConfig,
}

/// A live run ready to start: the networks loaded, the camera and the display open.
pub struct PreparedLive<'a> {
    board: &'a Board,
    source: Box<dyn FrameSource>,
    sink: Box<dyn FrameSink>,
    opts: LiveOptions,
}

/// Checks `config` against `board`, loads the networks, then opens the camera and the
/// display, in that order, so that a bad model fails before the camera is touched.
pub fn prepare_live<'a>(
    config: &LiveConfig,
    board: &'a Board,
) -> Result<PreparedLive<'a>, LiveError> {
    // Before the networks load: the frame size asked for (--size), else no larger
    // than the views; once the camera says what it delivers, again with that.
    let work = config.work_size.unwrap_or_else(|| board.view_size());
    let asked = config.size.unwrap_or(work);
    check_memory(config, board, asked)?;
    let depth = live_depth(config)?;
    let request = CameraRequest {
        format: config.format,
        size: config.size,
        fps: Some(config.fps),
        paced: config.realtime,
    };
    let source = crate::device::capture::open_source(&config.camera, &request)?;
    if source.size() != asked {
        check_memory(config, board, source.size())?;
    }
    let sink = crate::device::display::open_sink(&config.display, &config.out)?;
    let opts = LiveOptions {
        work_size: config.work_size,
        max_frames: config.frames,
        depth,
    };
    Ok(PreparedLive {
        board,
        source,
        sink,
        opts,
    })
}

impl PreparedLive<'_> {
    /// Shows frames until `stop` is set or the frame limit is reached.
    pub fn run(self, stop: &Arc<AtomicBool>) -> Result<LiveSummary, LiveError> {
        run_pipeline(self.source, self.sink, self.board, &self.opts, stop)
    }
}

/// Refuses a live run whose frames of `frame` pixels would not fit --max-memory: the
/// estimate of rendering one such photo for the board at the working size, with the
/// networks live loads, the panel and no quilt.
fn check_memory(args: &LiveConfig, board: &Board, frame: (u32, u32)) -> Result<(), LiveError> {
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
        network: reshading.then(|| {
            crate::pipeline::preflight::NetworkSize::of(
                &args.reshade,
                crate::pipeline::preflight::views_at_once(&args.reshade),
            )
        }),
        depth_network: depth,
        reshaded_at_once: if reshading {
            crate::pipeline::preflight::reshaded_at_once(&args.reshade, board.views())
        } else {
            0
        },
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
fn named_reshade_model(args: &ReshadeConfig) -> Option<PathBuf> {
    args.model
        .clone()
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
        .filter(|model| model.as_os_str() != "none")
}

/// The depth stage of `--depth network`, loaded before capture starts so that a bad model
/// fails before the camera is opened.
fn live_depth(args: &LiveConfig) -> Result<Option<LiveDepth>, LiveError> {
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
    let estimator = args.depth_net.estimator(DepthSource::Network)?;
    let reshader = live_reshader(&args.reshade)?;
    Ok(Some(LiveDepth {
        reshader,
        net: estimator.net()?,
        opts: *estimator.options(),
        max_age: args.depth_max_age,
        relocator: args.relocate.build_live(),
        hfov_deg: args.fov,
    }))
}

/// The reshading network when one is named explicitly (live has no default model: the
/// shipped network takes about 0.1 s per view on a CPU, seconds per frame for a board), built before the camera opens so that a bad model fails first.
fn live_reshader(
    args: &ReshadeConfig,
) -> Result<Option<Box<dyn Reshader + Send + Sync>>, LiveError> {
    match named_reshade_model(args) {
        Some(_) => Ok(Some(args.build()?)),
        None => Ok(None),
    }
}
