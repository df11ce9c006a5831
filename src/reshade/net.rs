//! The paper's reshading network as a [`Reshader`]: the photo and its disparity go through
//! the view-independent encoder once, the decoder runs per view with the view's camera,
//! and the predicted residual (reshaded − input) is added to the full-resolution photo.
//!
//! Per-view cost options, each measured by the benchmark (`bench_reshade`):
//! (a) `scale < 1` runs the network at a reduced working resolution and upsamples the
//!     residual (highlights are smooth); (b) `key_views` runs the decoder for K views
//!     and interpolates the residual between them; (c) `batch` puts several views in one
//!     decoder call; `parallel_views` runs views on several threads at once.

pub mod choice;
mod keys;
pub mod lobes;
mod models;

use models::find_models;
pub use models::{is_residual, manifests_where};

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use crate::depth::DepthMap;
use crate::engine::manifest::{self, ManifestError, Precision, Task, VerifiedModel};
use crate::engine::resample;
use crate::engine::{Engine, EngineError, ModelSource, Plan, Tensor};
use crate::io::photo::{SrgbImage, ONE_LEVEL};
use crate::reshade::{PreparedPhoto, ReshadeError, Reshader};
use crate::views::Intrinsics;

#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Engine(#[from] EngineError),
    #[error("{path}: {problem}")]
    Model { path: PathBuf, problem: String },
    #[error("reshading input: {0}")]
    Input(String),
}

impl From<NetError> for ReshadeError {
    fn from(e: NetError) -> Self {
        ReshadeError::Model(Box::new(e))
    }
}

/// Key views by default. The residual changes smoothly along a board's cameras: on the
/// 320 held-out path-traced views, each view blended halfway between two keys 1/7 of a
/// cone apart (8 keys, the worst place for a blend) keeps the changing views' mean gain
/// against the truth to three decimals (+0.424 dB), and the views it costs most (up to
/// 0.47 dB) are diffuse ones at 58-70 dB (docs/reshading.md, "Per-view cost options").
pub const DEFAULT_KEY_VIEWS: usize = 8;

/// The longest side, in pixels, the network runs at by default. The shipped model was
/// trained on whole scenes 128 pixels wide, and sees a larger photo of a scene as a
/// close-up: on 640x480 analytic renders it gains +0.69 dB where shading changes at
/// this size against +0.34 dB at 640 (most at 192, +0.81 dB, falling again at 128;
/// docs/reshading.md, "Working size"). 256 rather than 192 keeps more of a real photo's
/// small highlights, whose residual is upsampled.
pub const DEFAULT_MAX_SIDE: usize = 256;

/// Views whose predicted change touches under this share of their pixels by more than
/// one 8-bit level keep the photo exactly. Such a change is the network's noise on a view
/// whose shading does not move: on the 320 held-out path-traced views (the gate chosen on
/// their own validation scenes) it lifts whole diffuse scenes from 55.7 to 63.4 dB against
/// the photo while the views whose shading changes keep their gain within 0.01 dB
/// (models/reshade/README.md, "A gate for views that hardly change").
pub const DEFAULT_VIEW_GATE: f64 = 0.02;

/// How the per-view work is done; every choice other than the default trades fidelity
/// or memory for time (docs/benchmarks.md, "Per-view cost options").
#[derive(Clone, Debug, PartialEq)]
pub struct NetOptions {
    /// Working resolution as a fraction of the photo's, in (0, 1].
    pub scale: f64,
    /// The working resolution's longest side at most this many pixels (None: no limit);
    /// the smaller of this and `scale` applies.
    pub max_side: Option<usize>,
    /// Run the network for this many views and interpolate the rest (None: every view).
    pub key_views: Option<usize>,
    /// Views per decoder call.
    pub batch: usize,
    /// Views decoded at the same time on separate threads.
    pub parallel_views: usize,
    /// Camera offsets longer than this are shortened to it (None: the largest offset the
    /// model was trained on, from its manifest).
    pub max_offset: Option<f64>,
    /// A view whose change touches under this share of its pixels by more than a level
    /// keeps the photo ([`DEFAULT_VIEW_GATE`]; 0 keeps every view as predicted).
    pub gate: f64,
}

impl Default for NetOptions {
    fn default() -> Self {
        Self {
            scale: 1.0,
            max_side: Some(DEFAULT_MAX_SIDE),
            key_views: Some(DEFAULT_KEY_VIEWS),
            batch: 1,
            parallel_views: 1,
            max_offset: None,
            gate: DEFAULT_VIEW_GATE,
        }
    }
}

impl NetOptions {
    fn check(&self) -> Result<(), NetError> {
        let bad = |m: String| Err(NetError::Input(m));
        if !(self.scale > 0.0 && self.scale <= 1.0) {
            return bad(format!("reshade scale {} is outside (0, 1]", self.scale));
        }
        if self.max_side == Some(0) {
            return bad("the network's longest side must be at least 1 pixel".into());
        }
        if self.batch == 0 || self.parallel_views == 0 {
            return bad("batch and parallel views must be at least 1".into());
        }
        if self.key_views.is_some_and(|k| k < 2) {
            return bad("key views must be at least 2 (the two outermost views)".into());
        }
        if !(0.0..=1.0).contains(&self.gate) {
            return bad(format!(
                "reshade gate {} is not a share of the pixels in [0, 1]",
                self.gate
            ));
        }
        Ok(())
    }

    /// The size the network runs at for a `w`x`h` photo: `scale` of it, shrunk further
    /// to fit `max_side`.
    pub fn working_size(&self, w: usize, h: usize) -> (usize, usize) {
        let long = w.max(h).max(1) as f64;
        let s = match self.max_side {
            Some(m) => self.scale.min(m as f64 / long),
            None => self.scale,
        };
        let at = |n: usize| ((n as f64 * s).round() as usize).clamp(1, n.max(1));
        (at(w), at(h))
    }
}

enum Form {
    Single(Box<VerifiedModel>),
    Split {
        encoder: Box<VerifiedModel>,
        decoder: Box<VerifiedModel>,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Role {
    Single,
    Encoder,
    Decoder,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct PlanKey {
    role: Role,
    width: usize,
    height: usize,
    batch: usize,
}

pub struct NetReshader {
    form: Form,
    engine: Arc<dyn Engine>,
    options: NetOptions,
    multiple: usize,
    max_offset: f64,
    plans: Mutex<HashMap<PlanKey, Arc<dyn Plan>>>,
}

impl NetReshader {
    /// Loads the reshading model at `path`: a manifest (single graph, or either half of an
    /// encoder/decoder pair, whose partner is found beside it) or a directory holding them.
    pub fn load(
        path: &Path,
        precision: Precision,
        engine: Arc<dyn Engine>,
        options: NetOptions,
    ) -> Result<Self, NetError> {
        let form = find_models(path, precision)?;
        Self::new(form, engine, options)
    }

    fn new(form: Form, engine: Arc<dyn Engine>, options: NetOptions) -> Result<Self, NetError> {
        options.check()?;
        let first = match &form {
            Form::Single(m) => m,
            Form::Split { encoder, decoder } => {
                if encoder.manifest.size_multiple != decoder.manifest.size_multiple {
                    return Err(manifest::field_error(
                        &decoder.manifest_path,
                        "size_multiple",
                        "differs from the encoder's",
                    )
                    .into());
                }
                decoder
            }
        };
        let trained = first
            .manifest
            .camera
            .as_ref()
            .map_or(f64::INFINITY, |c| c.training_offset_range[1]);
        Ok(Self {
            multiple: first.manifest.size_multiple as usize,
            max_offset: options.max_offset.unwrap_or(trained),
            form,
            engine,
            options,
            plans: Mutex::new(HashMap::new()),
        })
    }

    pub fn options(&self) -> &NetOptions {
        &self.options
    }

    pub fn engine(&self) -> &dyn Engine {
        self.engine.as_ref()
    }

    /// Whether the encoder runs separately from the decoder.
    pub fn is_split(&self) -> bool {
        matches!(self.form, Form::Split { .. })
    }

    fn model(&self, role: Role) -> &VerifiedModel {
        match (&self.form, role) {
            (Form::Single(m), _) => m,
            (Form::Split { encoder, .. }, Role::Encoder) => encoder,
            (Form::Split { decoder, .. }, _) => decoder,
        }
    }

    /// The plan for `key`, optimised on first use and kept for later photos.
    fn plan(&self, key: PlanKey, shapes: &[(&str, Vec<usize>)]) -> Result<Arc<dyn Plan>, NetError> {
        let mut plans = self.plans.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(plan) = plans.get(&key) {
            return Ok(plan.clone());
        }
        let model = self.model(key.role);
        let task = model.manifest.task;
        let outputs = manifest::signature(task).expect("reshade task").outputs;
        let started = std::time::Instant::now();
        let plan = self.engine.plan(
            ModelSource {
                path: &model.model_path,
                bytes: &model.bytes,
                precision: model.manifest.precision,
            },
            shapes,
            outputs,
        )?;
        log::info!(
            "{}: {} plan for {}x{} batch {} ready in {:.0} ms",
            model.manifest.name,
            self.engine.name(),
            key.width,
            key.height,
            key.batch,
            started.elapsed().as_secs_f64() * 1e3
        );
        plans.insert(key, plan.clone());
        Ok(plan)
    }

    /// Runs the view-independent part for one photo (the encoder, in the split form).
    pub fn prepare_photo<'a>(
        &'a self,
        image: &'a SrgbImage,
        depth: &DepthMap,
    ) -> Result<NetPhoto<'a>, NetError> {
        let (w, h) = (image.width() as usize, image.height() as usize);
        if depth.width() != w || depth.height() != h {
            return Err(NetError::Input(format!(
                "depth is {}x{} but the photo is {w}x{h}",
                depth.width(),
                depth.height()
            )));
        }
        let (ww, wh) = self.options.working_size(w, h);
        let (pw, ph) = (round_up(ww, self.multiple), round_up(wh, self.multiple));
        let full = planar(image);
        let disparity: Vec<f32> = depth.data().iter().map(|&z| disparity(z)).collect();
        let work = resample::resize(&full, w, h, ww, wh);
        let work_disparity = resample::resize(&disparity, w, h, ww, wh);
        let image_t = Tensor::new(
            vec![1, 3, ph, pw],
            resample::pad_replicate(&work, ww, wh, pw, ph),
        );
        let disparity_t = Tensor::new(
            vec![1, 1, ph, pw],
            resample::pad_replicate(&work_disparity, ww, wh, pw, ph),
        );
        let encoded = if self.is_split() {
            let key = PlanKey {
                role: Role::Encoder,
                width: pw,
                height: ph,
                batch: 1,
            };
            let plan = self.plan(
                key,
                &[
                    ("image", image_t.shape.clone()),
                    ("disparity", disparity_t.shape.clone()),
                ],
            )?;
            let outputs = plan.run(&[("image", &image_t), ("disparity", &disparity_t)])?;
            let names = manifest::signature(Task::ReshadeEncoder)
                .expect("encoder")
                .outputs;
            names.iter().map(|n| n.to_string()).zip(outputs).collect()
        } else {
            Vec::new()
        };
        Ok(NetPhoto {
            net: self,
            image,
            full,
            work,
            size: (w, h),
            work_size: (ww, wh),
            padded: (pw, ph),
            image_t,
            disparity_t,
            encoded,
            clamped: AtomicUsize::new(0),
            gated: AtomicUsize::new(0),
        })
    }

    fn limit_offset(&self, centre: [f64; 3]) -> ([f32; 3], bool) {
        let len = centre.iter().map(|c| c * c).sum::<f64>().sqrt();
        let k = if len > self.max_offset {
            self.max_offset / len
        } else {
            1.0
        };
        (centre.map(|c| (c * k) as f32), k < 1.0)
    }
}

impl Reshader for NetReshader {
    fn description(&self) -> String {
        let m = &self.model(Role::Decoder).manifest;
        let o = &self.options;
        // The weights' checksums, not only name and version: a retrained model keeps its
        // name, and the gallery's done-markers must see the change.
        let short = |sha: &str| sha.trim().chars().take(12).collect::<String>();
        let weights = if self.is_split() {
            let e = &self.model(Role::Encoder).manifest;
            format!(
                "encoder {} + decoder {}",
                short(&e.sha256),
                short(&m.sha256)
            )
        } else {
            format!("single graph {}", short(&m.sha256))
        };
        format!(
            "{} {} ({}, head residual, {weights}, engine {} x{} threads, scale {}, longest side {}, key views {}, batch {}, parallel views {}, gate {})",
            m.name,
            m.version,
            m.precision,
            self.engine.name(),
            self.engine.threads(),
            o.scale,
            o.max_side.map_or("unlimited".into(), |m| format!("{m} px")),
            o.key_views.map_or("all".into(), |k| k.to_string()),
            o.batch,
            o.parallel_views,
            o.gate,
        )
    }

    fn prepare<'a>(
        &'a self,
        image: &'a SrgbImage,
        depth: &'a DepthMap,
        _camera: &Intrinsics,
    ) -> Result<Box<dyn PreparedPhoto + 'a>, ReshadeError> {
        // The residual head never sees the camera's geometry, only offsets.
        Ok(Box::new(self.prepare_photo(image, depth)?))
    }
}

/// A photo after the encoder: ready to be reshaded for any number of views.
pub struct NetPhoto<'a> {
    net: &'a NetReshader,
    image: &'a SrgbImage,
    full: Vec<f32>,
    work: Vec<f32>,
    size: (usize, usize),
    work_size: (usize, usize),
    padded: (usize, usize),
    image_t: Tensor,
    disparity_t: Tensor,
    encoded: Vec<(String, Tensor)>,
    clamped: AtomicUsize,
    /// Views that kept the photo at the gate, since the last report.
    gated: AtomicUsize,
}

impl NetPhoto<'_> {
    /// The photo reshaded for every camera in `centres`, using the options' key views,
    /// batching and parallelism.
    pub fn reshade_views(&self, centres: &[[f64; 3]]) -> Result<Vec<SrgbImage>, NetError> {
        self.views(centres).collect()
    }

    /// The photo reshaded for every camera in `centres`, in order, computed as the views
    /// are pulled. With every view a key view, `--reshade-batch × --parallel-views` views
    /// are decoded at a time; with fewer key views, the key views' residuals are decoded
    /// at the first pull and the others interpolated one by one. A caller that consumes
    /// each view before pulling the next thus holds a few views, not all of them.
    pub fn views<'s>(&'s self, centres: &'s [[f64; 3]]) -> ViewStream<'s> {
        let sources = keys::plan(centres, self.net.options.key_views.unwrap_or(usize::MAX));
        ViewStream {
            photo: self,
            centres,
            every_view_is_a_key: sources.iter().all(|s| *s == keys::Source::Key),
            sources,
            keys: None,
            pending: std::collections::VecDeque::new(),
            next: 0,
        }
    }

    /// Logs (once per stream) how many of `asked` views were beyond the trained range.
    fn report_clamped(&self, asked: usize) {
        let clamped = self.clamped.swap(0, Ordering::Relaxed);
        if clamped > 0 {
            log::info!(
                "{clamped} of {asked} reshaded views asked for camera offsets beyond {:.3} (the trained range); reshaded as at that distance",
                self.net.max_offset
            );
        }
    }

    /// Logs (once per stream) how many of `asked` views kept the photo at the gate.
    fn report_gated(&self, asked: usize) {
        let gated = self.gated.swap(0, Ordering::Relaxed);
        if gated > 0 {
            log::info!(
                "{gated} of {asked} views keep the photo's shading: the network changed under {} % of their pixels by more than a level (--reshade-gate)",
                100.0 * self.net.options.gate
            );
        }
    }

    /// Working-resolution residuals for `centres`, in order.
    fn residuals(&self, centres: &[[f64; 3]]) -> Result<Vec<Vec<f32>>, NetError> {
        let chunks: Vec<&[[f64; 3]]> = centres.chunks(self.net.options.batch).collect();
        let batches = crate::parallel::map(chunks.len(), self.net.options.parallel_views, |i| {
            self.run_batch(chunks[i])
        })?;
        Ok(batches.into_iter().flatten().collect())
    }

    /// One network call for `centres.len()` views; their residuals at working resolution.
    fn run_batch(&self, centres: &[[f64; 3]]) -> Result<Vec<Vec<f32>>, NetError> {
        let b = centres.len();
        let mut camera = Vec::with_capacity(3 * b);
        for &c in centres {
            let (limited, was_clamped) = self.net.limit_offset(c);
            if was_clamped {
                self.clamped.fetch_add(1, Ordering::Relaxed);
            }
            camera.extend(limited);
        }
        let camera = Tensor::new(vec![b, 3], camera);
        let inputs: Vec<(&str, &Tensor)> = if self.net.is_split() {
            std::iter::once(("image", &self.image_t))
                .chain(self.encoded.iter().map(|(n, t)| (n.as_str(), t)))
                .collect()
        } else {
            vec![("image", &self.image_t), ("disparity", &self.disparity_t)]
        };
        // Batched plans take every input with the batch's size.
        let owned: Vec<(&str, Tensor)> = if b > 1 {
            inputs.iter().map(|(n, t)| (*n, repeat(t, b))).collect()
        } else {
            Vec::new()
        };
        let mut feed: Vec<(&str, &Tensor)> = if b > 1 {
            owned.iter().map(|(n, t)| (*n, t)).collect()
        } else {
            inputs
        };
        feed.push(("camera", &camera));
        let (pw, ph) = self.padded;
        let role = if self.net.is_split() {
            Role::Decoder
        } else {
            Role::Single
        };
        let key = PlanKey {
            role,
            width: pw,
            height: ph,
            batch: b,
        };
        let shapes: Vec<(&str, Vec<usize>)> =
            feed.iter().map(|(n, t)| (*n, t.shape.clone())).collect();
        let plan = self.net.plan(key, &shapes)?;
        let out = plan.run(&feed)?.remove(0);
        let expected = [b, 3, ph, pw];
        if out.shape != expected {
            return Err(NetError::Model {
                path: self.net.model(role).model_path.clone(),
                problem: format!("output is {:?}; expected {expected:?}", out.shape),
            });
        }
        let (ww, wh) = self.work_size;
        Ok(out
            .data
            .chunks_exact(3 * pw * ph)
            .map(|item| {
                let mut r = resample::crop(item, pw, ph, ww, wh);
                for (v, x) in r.iter_mut().zip(&self.work) {
                    *v -= x;
                }
                r
            })
            .collect())
    }

    /// The full-resolution photo plus a working-resolution residual, clamped to [0, 1].
    fn compose(&self, residual: &[f32]) -> SrgbImage {
        self.compose_upsampled(&self.upsampled(residual), None)
    }

    /// A working-resolution residual at the photo's size (itself where the network ran
    /// at the photo's size).
    fn upsampled<'r>(&self, residual: &'r [f32]) -> Cow<'r, [f32]> {
        let (w, h) = self.size;
        let (ww, wh) = self.work_size;
        if (ww, wh) == (w, h) {
            residual.into()
        } else {
            resample::resize(residual, ww, wh, w, h).into()
        }
    }

    /// Residuals at the photo's size, upsampled on every core where they are not.
    fn all_upsampled(&self, residuals: Vec<Vec<f32>>) -> Vec<Vec<f32>> {
        if self.work_size == self.size {
            return residuals;
        }
        let cores = crate::parallel::cores();
        crate::parallel::map(residuals.len(), cores, |k| {
            Ok::<_, std::convert::Infallible>(self.upsampled(&residuals[k]).into_owned())
        })
        .unwrap_or_else(|never| match never {})
    }

    /// The photo plus a residual at its size, or plus the blend `a + (b − a)·t` of two
    /// (upsampling is linear, so blending after it is blending before), clamped to [0, 1];
    /// the photo itself where the change passes the gate at too few pixels.
    fn compose_upsampled(&self, a: &[f32], blend: Option<(&[f32], f32)>) -> SrgbImage {
        let (w, h) = self.size;
        let plane = w * h;
        let mut rgb = vec![0.0f32; 3 * plane];
        let mut changed = 0usize;
        for (i, px) in rgb.chunks_exact_mut(3).enumerate() {
            let mut moved = false;
            for (c, v) in px.iter_mut().enumerate() {
                let j = c * plane + i;
                let residual = match blend {
                    Some((b, t)) => a[j] + (b[j] - a[j]) * t,
                    None => a[j],
                };
                *v = (self.full[j] + residual).clamp(0.0, 1.0);
                moved |= (*v - self.full[j]).abs() > ONE_LEVEL;
            }
            changed += usize::from(moved);
        }
        if (changed as f64) < self.net.options.gate * plane as f64 {
            self.gated.fetch_add(1, Ordering::Relaxed);
            return self.image.clone();
        }
        let buffer =
            image::Rgb32FImage::from_raw(w as u32, h as u32, rgb).expect("buffer matches size");
        SrgbImage::from_rgb32f(buffer)
    }

    /// Milliseconds per operator type of one decoder run (the single graph's, in that
    /// form) for a camera at `centre`, as tract executes it.
    pub fn profile(
        &self,
        engine: &crate::engine::tract::TractEngine,
        centre: [f64; 3],
    ) -> Result<Vec<(String, f64)>, NetError> {
        let camera = Tensor::new(vec![1, 3], self.net.limit_offset(centre).0.to_vec());
        let mut feed: Vec<(&str, &Tensor)> = if self.net.is_split() {
            std::iter::once(("image", &self.image_t))
                .chain(self.encoded.iter().map(|(n, t)| (n.as_str(), t)))
                .collect()
        } else {
            vec![("image", &self.image_t), ("disparity", &self.disparity_t)]
        };
        feed.push(("camera", &camera));
        let model = self.net.model(if self.net.is_split() {
            Role::Decoder
        } else {
            Role::Single
        });
        let source = ModelSource {
            path: &model.model_path,
            bytes: &model.bytes,
            precision: model.manifest.precision,
        };
        let outputs = manifest::signature(model.manifest.task)
            .expect("reshade task")
            .outputs;
        Ok(engine.profile(source, &feed, outputs)?)
    }

    /// The input photo this was prepared from.
    pub fn photo(&self) -> &SrgbImage {
        self.image
    }

    /// The padded working-resolution size the network runs at.
    pub fn network_size(&self) -> (usize, usize) {
        self.padded
    }
}

/// The views of a [`NetPhoto`] in order, decoded as they are pulled
/// ([`NetPhoto::views`]). After an error it ends.
pub struct ViewStream<'s> {
    photo: &'s NetPhoto<'s>,
    centres: &'s [[f64; 3]],
    sources: Vec<keys::Source>,
    /// Then views are decoded a few at a time; otherwise all key views at the first pull.
    every_view_is_a_key: bool,
    /// With interpolated views: the key views and their residuals upsampled to the
    /// photo's size, in view order.
    keys: Option<(Vec<usize>, Vec<Vec<f32>>)>,
    /// Views made but not yet pulled.
    pending: std::collections::VecDeque<SrgbImage>,
    next: usize,
}

impl ViewStream<'_> {
    /// Decodes the next `--reshade-batch × --parallel-views` views into `pending`.
    fn decode_next_views(&mut self) -> Result<(), NetError> {
        let options = &self.photo.net.options;
        let at_once = options.batch.max(1) * options.parallel_views.max(1);
        let end = self.centres.len().min(self.next + at_once);
        let residuals = self.photo.residuals(&self.centres[self.next..end])?;
        self.pending = residuals.iter().map(|r| self.photo.compose(r)).collect();
        Ok(())
    }

    /// The next views from the key views' residuals (decoded on first use) into
    /// `pending`, as many at once as there are cores: blending, upsampling and adding
    /// each view's residual is a few milliseconds per view at a 12 MP photo's working
    /// size, and the caller relocates the views it pulls on every core at once.
    fn interpolate_next_views(&mut self) -> Result<(), NetError> {
        if self.keys.is_none() {
            let key_views: Vec<usize> = (0..self.sources.len())
                .filter(|&k| self.sources[k] == keys::Source::Key)
                .collect();
            let centres: Vec<[f64; 3]> = key_views.iter().map(|&k| self.centres[k]).collect();
            let residuals = self.photo.residuals(&centres)?;
            self.photo.report_clamped(key_views.len());
            self.keys = Some((key_views, self.photo.all_upsampled(residuals)));
        }
        let cores = crate::parallel::cores();
        let first = self.next;
        let count = cores.min(self.centres.len() - first);
        let this = &*self;
        let views = crate::parallel::map(count, cores, |i| {
            Ok::<_, NetError>(this.view_of_keys(first + i))
        })?;
        self.pending.extend(views);
        Ok(())
    }

    /// View `v` from the key views' residuals: a key view's own, or a blend of the two
    /// key views beside it.
    fn view_of_keys(&self, v: usize) -> SrgbImage {
        let (key_views, residuals) = self.keys.as_ref().expect("key views decoded first");
        let slot = |k: usize| {
            key_views
                .iter()
                .position(|&key| key == k)
                .expect("a key view")
        };
        match self.sources[v] {
            keys::Source::Key => self.photo.compose_upsampled(&residuals[slot(v)], None),
            keys::Source::Blend { a, b, t } => self
                .photo
                .compose_upsampled(&residuals[slot(a)], Some((&residuals[slot(b)], t))),
        }
    }
}

impl Iterator for ViewStream<'_> {
    type Item = Result<SrgbImage, NetError>;

    fn next(&mut self) -> Option<Self::Item> {
        let n = self.centres.len();
        if self.next >= n {
            return None;
        }
        if self.pending.is_empty() {
            let decoded = if self.every_view_is_a_key {
                self.decode_next_views()
            } else {
                self.interpolate_next_views()
            };
            if let Err(e) = decoded {
                self.next = n;
                return Some(Err(e));
            }
        }
        self.next += 1;
        if self.next == n {
            if self.every_view_is_a_key {
                self.photo.report_clamped(n);
            }
            self.photo.report_gated(n);
        }
        Some(Ok(self
            .pending
            .pop_front()
            .expect("decoded at least one view")))
    }
}

impl PreparedPhoto for NetPhoto<'_> {
    fn reshade(&self, centre: [f64; 3]) -> Result<SrgbImage, ReshadeError> {
        Ok(self.reshade_views(&[centre])?.remove(0))
    }

    fn reshade_each<'s>(
        &'s self,
        centres: &'s [[f64; 3]],
    ) -> Box<dyn Iterator<Item = Result<SrgbImage, ReshadeError>> + 's> {
        Box::new(self.views(centres).map(|v| v.map_err(ReshadeError::from)))
    }
}

/// The network's disparity input: `clamp(0.25 / depth, 0, 1)`; depth that is missing
/// (zero, negative or not a number) counts as infinitely far.
pub fn disparity(depth: f32) -> f32 {
    if depth > 0.0 {
        (0.25 / depth).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

fn round_up(n: usize, multiple: usize) -> usize {
    n.div_ceil(multiple) * multiple
}

/// Interleaved RGB to three planes.
fn planar(image: &SrgbImage) -> Vec<f32> {
    let plane = image.width() as usize * image.height() as usize;
    let mut out = vec![0.0f32; 3 * plane];
    for (i, px) in image.data().chunks_exact(3).enumerate() {
        for c in 0..3 {
            out[c * plane + i] = px[c];
        }
    }
    out
}

/// `t` (batch 1) repeated `b` times along the batch axis.
fn repeat(t: &Tensor, b: usize) -> Tensor {
    let mut shape = t.shape.clone();
    shape[0] = b;
    Tensor::new(shape, t.data.repeat(b))
}

#[cfg(test)]
mod tests;
