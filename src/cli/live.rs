//! `reshader live`: a camera shown on a panel, frame by frame.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use clap::Args;

use reshader::device::capture::live::{prepare_live, LiveConfig, LiveDepthMode};
use reshader::device::capture::{PixelFormat, MAX_FRAME_SIDE};

use crate::args::{keyword, parse_size, EstimateArgs, RelocateArgs, ReshadeArgs};
use crate::signals::stop_on_signals;

#[derive(Args, Debug)]
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
    #[arg(long, value_parser = frame_size)]
    pub size: Option<(u32, u32)>,
    /// Working resolution of the views, WIDTHxHEIGHT [default: the board's view size].
    #[arg(long, value_parser = frame_size)]
    pub work_size: Option<(u32, u32)>,
    /// Stop after this many frames have been shown.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Replay a recording at its recorded pace (dropping frames when behind) instead of
    /// as fast as the pipeline takes them.
    #[arg(long)]
    pub realtime: bool,
    /// Depth for the views: off (flat: every view is the camera frame) or network.
    #[arg(long, value_parser = keyword::<LiveDepthMode>(), default_value = "off")]
    pub depth: LiveDepthMode,
    /// Start the next key frame (depth, relocation maps, reshading) on the worker once the
    /// last is this many milliseconds old (0: every frame is a key frame, made before it
    /// is shown).
    #[arg(long, default_value_t = 500)]
    pub depth_max_age_ms: u64,
    /// Horizontal field of view of the camera in degrees, for relocating the views.
    #[arg(long, default_value_t = reshader::io::photo::DEFAULT_HFOV_DEG)]
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
With --depth network the depth network runs on a key frame and every view is relocated
with its depth (--relocate). Each view of a key frame becomes a map of where its pixels
take their colours from in the frame, with the view's reshading as a change to the frame;
every camera frame is then shown through the last key frame's maps (milliseconds a frame),
while the next key frame (depth, relocation, reshading: most of a second) is made on a
worker thread once the last one is older than --depth-max-age-ms. With 0, or with a
relocation that cannot give maps (--relocate mesh, --border inpaint), every frame is its
own key frame, made before it is shown.

Live views keep the camera's shading unless a reshading model is named (--model, or
$RESHADER_MODEL; needs --depth network): unlike render, live does not fall back to
models/reshade. A key frame's reshading is applied to the frames shown until the next.

Examples:
  reshader live --camera /dev/video0 --list-formats
  reshader live --camera /dev/video0 --board looking-glass-portrait --display fb:/dev/fb0 -v
  reshader live --camera /dev/video0 --board looking-glass-portrait --depth network \\
      --work-size 210x280 --depth-max-age-ms 1000 -v
  reshader live --camera recording.rshfrm --board looking-glass-portrait --frames 300 -v";

fn frame_size(s: &str) -> Result<(u32, u32), String> {
    parse_size(s, 1, MAX_FRAME_SIDE)
}

impl LiveArgs {
    fn config(&self) -> LiveConfig {
        LiveConfig {
            camera: self.camera.clone(),
            fps: self.fps,
            display: self.display.clone(),
            out: self.out.clone(),
            format: self.format,
            size: self.size,
            work_size: self.work_size,
            frames: self.frames,
            realtime: self.realtime,
            depth: self.depth,
            depth_max_age: Duration::from_millis(self.depth_max_age_ms),
            fov: self.fov,
            relocate: self.relocate.config(),
            depth_net: self.estimate.config(),
            reshade: self.reshade.config(),
        }
    }
}

/// Runs `reshader live` until SIGINT/SIGTERM or --frames, and prints its summary.
pub fn live(args: &LiveArgs) -> Result<()> {
    if args.list_formats {
        for format in reshader::device::capture::list_formats(&args.camera)? {
            print!("{format}");
        }
        return Ok(());
    }
    let board_name = args
        .board
        .as_deref()
        .ok_or_else(|| anyhow::anyhow!("--board is required unless --list-formats is given"))?;
    let board = reshader::pipeline::load_board(board_name, args.calibration.as_deref())?;
    let prepared = prepare_live(&args.config(), &board)?;
    let stop = stop_on_signals()?;
    let summary = prepared.run(&stop)?;
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
