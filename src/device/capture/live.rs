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

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use image::imageops::{self, FilterType};
use image::RgbImage;
use interleave::{Board, Weaver};

mod setup;

pub use setup::{prepare_live, LiveConfig, LiveDepthMode, PreparedLive};

use super::{CaptureError, Frame, FrameSource};
use crate::depth::net::{self as depth_net, DepthNet, DepthNetError, StageOptions};
use crate::depth::DepthMap;
use crate::device::display::{DisplayError, FrameSink};
use crate::io::photo::SrgbImage;
use crate::io::record::Timings;
use crate::pipeline::progress::Progress;
use crate::pipeline::{render_views, BoardRig, Fitted};
use crate::relocate::map::{ShadingChange, ViewMap};
use crate::relocate::{RelocateError, Relocator};
use crate::reshade::net::NetError;
use crate::reshade::{ReshadeError, Reshader, TrainingFrame};
use crate::views::{Intrinsics, ViewCamera, ViewError};

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
    #[error(transparent)]
    Scale(#[from] crate::depth::ScaleError),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
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
        views: None,
        key_at: Instant::now(),
    });
    let mut panel = RgbImage::new(0, 0);
    let keys = KeySlot::default();
    let result = std::thread::scope(|scope| {
        if let Some(live) = opts.depth.as_ref().filter(|d| !d.max_age.is_zero()) {
            let (keys, views) = (&keys, weaver.views());
            let cone = f64::from(board.view_cone_deg());
            scope.spawn(move || keys.serve(live, cone, views));
        }
        let result = loop {
            if stop.load(Ordering::SeqCst) || opts.max_frames.is_some_and(|m| run.total.frames >= m)
            {
                break Ok(());
            }
            let Some(next) = mailbox.take(stop) else {
                break Ok(());
            };
            let frame = match next {
                Ok(frame) => frame,
                Err(e) => break Err(e),
            };
            if let Err(e) = run.process(&frame, &weaver, &keys, &mut panel, sink.as_mut()) {
                break Err(e);
            }
        };
        keys.close();
        result
    });
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

/// The depth stage's settings, the last depth map with its age, and the views it gives.
struct DepthState<'a> {
    live: &'a LiveDepth,
    cone: f64,
    latest: Option<(DepthMap, Instant)>,
    /// The latest depth map's views as lookups into the frame, with their reshading;
    /// None where the relocator gives no maps, and every frame is rendered in full.
    views: Option<Arc<MappedViews>>,
    /// When the frame those views were made from was taken up.
    key_at: Instant,
}

/// The views of one depth map: where each view pixel takes its colours from in the
/// frame, and each view's reshading as a change to the frame, both made on the frame the
/// depth was estimated on and applied to every frame until the next estimate.
struct MappedViews {
    maps: Vec<ViewMap>,
    /// One per view, or none without reshading.
    changes: Vec<ShadingChange>,
}

impl DepthState<'_> {
    /// Estimates depth for `work` unless the last map is still fresh; says whether it ran.
    fn refresh(&mut self, work: &RgbImage) -> Result<bool, LiveError> {
        let stale = self
            .latest
            .as_ref()
            .is_none_or(|(_, at)| at.elapsed() > self.live.max_age);
        if stale {
            let size = depth_net::photo_size(work);
            let (map, _) = depth_net::network_depth(&self.live.net, work, size, &self.live.opts)?;
            self.latest = Some((map, Instant::now()));
        }
        Ok(stale)
    }

    /// The frame fitted to its depth, the views' cameras and the reshading cameras.
    fn scene(&self, work: &RgbImage, count: usize) -> Result<LiveScene, LiveError> {
        let (depth, _) = self
            .latest
            .as_ref()
            .expect("depth refreshed before the views");
        let source = Intrinsics::from_hfov(work.width(), work.height(), self.live.hfov_deg);
        let fitted = Fitted {
            image: SrgbImage::from_rgb8(work),
            depth: depth.clone(),
            source,
            reference: source.cover(work.width(), work.height()),
        };
        let rigs = BoardRig::for_views(
            (count, self.cone),
            (depth, &fitted.reference),
            (None, None),
            None,
        )?;
        Ok(LiveScene {
            cameras: rigs.rig.cameras(&fitted.reference),
            shading: rigs.shading.centres(),
            frame: TrainingFrame::for_focus(rigs.rig.focus),
            fitted,
        })
    }

    /// The views of the latest depth map as maps, or None where the relocator cannot
    /// give them.
    fn mapped_views(
        &self,
        work: &RgbImage,
        count: usize,
    ) -> Result<Option<MappedViews>, LiveError> {
        let scene = self.scene(work, count)?;
        let fitted = &scene.fitted;
        let prepared = self.live.relocator.prepare(
            &fitted.image,
            &fitted.depth,
            &fitted.source,
            &scene.cameras,
        )?;
        let maps = crate::parallel::map(scene.cameras.len(), crate::parallel::cores(), |i| {
            Ok::<_, LiveError>(prepared.view_map(&scene.cameras[i]))
        })?;
        let Some(maps) = maps.into_iter().collect::<Option<Vec<_>>>() else {
            return Ok(None);
        };
        let changes = match &self.live.reshader {
            Some(r) => {
                let depth = scene.frame.depth(&fitted.depth);
                let reshading = r.prepare(&fitted.image, &depth, &fitted.source)?;
                let centres: Vec<[f64; 3]> = scene
                    .shading
                    .iter()
                    .map(|&c| scene.frame.camera(c))
                    .collect();
                reshading
                    .reshade_each(&centres)
                    .map(|view| Ok(ShadingChange::between(&fitted.image, &view?)?))
                    .collect::<Result<_, LiveError>>()?
            }
            None => Vec::new(),
        };
        let bytes: usize = maps.iter().map(ViewMap::bytes).sum::<usize>()
            + changes.iter().map(ShadingChange::bytes).sum::<usize>();
        log::debug!(
            "live: {} views mapped, {}",
            maps.len(),
            crate::io::limits::Bytes(bytes as u64)
        );
        Ok(Some(MappedViews { maps, changes }))
    }
}

impl DepthState<'_> {
    /// Takes up the views of a key frame the worker finished, and hands it `work` as the
    /// next key frame when the current one is older than `--depth-max-age-ms` and it is
    /// idle; says whether new views were taken up.
    fn take_key(&mut self, keys: &KeySlot, work: &RgbImage) -> Result<bool, LiveError> {
        let finished = keys.take_finished()?;
        if let Some((views, at)) = finished.clone() {
            self.views = Some(views);
            self.key_at = at;
        }
        if self.key_at.elapsed() > self.live.max_age {
            keys.offer(work);
        }
        Ok(finished.is_some())
    }
}

/// Key frames for the worker thread: depth and the views' maps for a new frame are
/// made there, on the cores the loop leaves idle, while the loop keeps showing every
/// camera frame through the last key frame's maps. The depth network and the LDI take
/// most of a second for a frame; applying maps takes milliseconds.
#[derive(Default)]
struct KeySlot {
    state: Mutex<KeyState>,
    wake: Condvar,
}

#[derive(Default)]
struct KeyState {
    request: Option<(RgbImage, Instant)>,
    busy: bool,
    finished: Option<Result<(Arc<MappedViews>, Instant), LiveError>>,
    closed: bool,
}

impl KeySlot {
    /// Hands `work` to the worker unless it is busy or has a result waiting.
    fn offer(&self, work: &RgbImage) {
        let mut state = self.state.lock().expect("key slot poisoned");
        if !state.busy && state.request.is_none() && state.finished.is_none() {
            state.request = Some((work.clone(), Instant::now()));
            self.wake.notify_all();
        }
    }

    fn take_finished(&self) -> Result<Option<(Arc<MappedViews>, Instant)>, LiveError> {
        let finished = self
            .state
            .lock()
            .expect("key slot poisoned")
            .finished
            .take();
        finished.transpose()
    }

    fn close(&self) {
        self.state.lock().expect("key slot poisoned").closed = true;
        self.wake.notify_all();
    }

    /// The worker: makes depth and views for each key frame offered until closed.
    fn serve(&self, live: &LiveDepth, cone: f64, views: usize) {
        while let Some((work, at)) = self.next_request() {
            let started = Instant::now();
            let mut state = DepthState {
                live,
                cone,
                latest: None,
                views: None,
                key_at: at,
            };
            let result = state.refresh(&work).and_then(|_| {
                state
                    .mapped_views(&work, views)?
                    .map(|v| (Arc::new(v), at))
                    .ok_or_else(|| LiveError::Options("the relocator gave no view maps".into()))
            });
            log::debug!(
                "live: key frame ready in {:.0} ms",
                started.elapsed().as_secs_f64() * 1e3
            );
            let mut state = self.state.lock().expect("key slot poisoned");
            state.busy = false;
            state.finished = Some(result);
        }
    }

    fn next_request(&self) -> Option<(RgbImage, Instant)> {
        let mut state = self.state.lock().expect("key slot poisoned");
        loop {
            if state.closed {
                return None;
            }
            if let Some(request) = state.request.take() {
                state.busy = true;
                return Some(request);
            }
            state = self.wake.wait(state).expect("key slot poisoned");
        }
    }
}

/// What the views of a frame are rendered from.
struct LiveScene {
    fitted: Fitted,
    cameras: Vec<ViewCamera>,
    shading: Vec<[f64; 3]>,
    frame: TrainingFrame,
}

impl MappedViews {
    /// Every view of `work`, into `views` (reused between frames), a band of views per
    /// core.
    fn apply(&self, work: &RgbImage, views: &mut Vec<RgbImage>) -> Result<(), LiveError> {
        views.resize_with(self.maps.len(), || RgbImage::new(0, 0));
        let band = self.maps.len().div_ceil(crate::parallel::cores()).max(1);
        std::thread::scope(|scope| {
            let jobs: Vec<_> = views
                .chunks_mut(band)
                .enumerate()
                .map(|(b, chunk)| {
                    scope.spawn(move || {
                        for (j, view) in chunk.iter_mut().enumerate() {
                            let i = b * band + j;
                            self.maps[i].apply(work, self.changes.get(i), view)?;
                        }
                        Ok::<_, RelocateError>(())
                    })
                })
                .collect();
            jobs.into_iter()
                .try_for_each(|job| job.join().expect("a view band panicked"))
        })?;
        Ok(())
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
        keys: &KeySlot,
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
            Some(state) if state.views.is_some() && !state.live.max_age.is_zero() => {
                estimated = state.take_key(keys, &work)?;
                let t = Instant::now();
                if let Some(mapped) = &state.views {
                    mapped.apply(&work, &mut self.views)?;
                }
                times[3] = t.elapsed();
            }
            Some(state) => {
                let t = Instant::now();
                estimated = state.refresh(&work)?;
                times[2] = t.elapsed();
                let t = Instant::now();
                if estimated {
                    state.views = state.mapped_views(&work, weaver.views())?.map(Arc::new);
                    state.key_at = Instant::now();
                }
                match &state.views {
                    Some(mapped) => mapped.apply(&work, &mut self.views)?,
                    None => self.views = relocated_views(&work, state, weaver.views())?,
                }
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

/// The views of a frame with depth, rendered as `render` renders a photo's: the same
/// rigs (the views' and, wider, the reshading cameras'), reshading and relocation.
fn relocated_views(
    work: &RgbImage,
    state: &DepthState,
    count: usize,
) -> Result<Vec<RgbImage>, LiveError> {
    let scene = state.scene(work, count)?;
    Ok(render_views(
        &scene.fitted,
        (&scene.cameras, &scene.shading),
        scene.frame,
        state.live.reshader.as_deref().map(|r| r as &dyn Reshader),
        &*state.live.relocator,
        &Progress::hidden(),
        &mut Timings::default(),
    )?)
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
