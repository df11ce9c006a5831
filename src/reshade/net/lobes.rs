//! The lobe head (DESIGN.md, "The lobe head") as a [`Reshader`]: the network takes no
//! camera and runs once per photo, giving per pixel K spherical-Gaussian lobes
//! (axis μ, sharpness λ, RGB amplitude a); each view is then a closed form evaluated here,
//! in plain Rust, with no engine call:
//!
//! ```text
//! w  = normalize(4·d·c − r)      (the direction from the pixel's 3-D point to the camera c)
//! w0 = normalize(−r)             (the same for the input camera, c = 0)
//! change  = Σ_j a_j · (exp(λ_j (μ_j·w − 1)) − exp(λ_j (μ_j·w0 − 1)))
//! change' = soft threshold of change by the dead zone, per channel
//! view    = clamp(photo + change', 0, 1)
//! ```
//!
//! with d the network's disparity input (0.25 / depth) and r = K⁻¹[u, v, 1] the pixel's ray
//! at the network's resolution (pixel centres at integer coordinates, OpenCV axes).
//!
//! The `lobes-slide` head adds, before the threshold, a layer of the photo that moves as a
//! reflected image does (model.slide_change): per pixel the share f of the photo (per
//! colour) that is such light, S = photo·f, and ρ, how far behind the surface its image
//! lies (0 on the surface, 1 at infinity). A view moves S by the parallax its depth has
//! relative to the surface and samples it back:
//!
//! ```text
//! p(z)    = (r − z·c)_xy / max((r − z·c)_z, 0.05)      (a point at z·0.25/d… seen from c)
//! s       = p(q·(1 − ρ)) − p(q),  q = d / 0.25           (normalised units; × fx, fy in px)
//! change += S(x − s_x·fx, y − s_y·fy) − S(x, y)          (bilinear, clamped to the image)
//! ```
//!
//! Domain `linear-clamped` (head `lobes`) sums the lobes in linear light instead, per
//! colour, with L = photo^2.2, S = Σ_j a_j G_j(w) and S0 the same at w0:
//!
//! ```text
//! k      = 1 where the photo clipped, else min(1, L / S0)   (never take more than the pixel has)
//! dug    = max(S0 − L, 0) where the photo clipped, else 0  (a clipped highlight may exceed white)
//! change = soft threshold of min(L + k (S − S0) + dug, 1) − L by the dead zone
//! view   = photo where change = 0, else max(L + change, 1e-4)^(1/2.2)
//! ```
//!
//! This is
//! `shade_lobes` of the training toolchain's model.py, operation for operation in f32, so
//! that c = 0 gives the photo exactly and other cameras match PyTorch to float rounding.
//!
//! The network runs at the same working resolution the residual head uses (`--reshade-scale`)
//! and, like the residual head, the per-view *change* is upsampled to the photo's
//! resolution, not the lobe parameters: axes and sharpnesses do not interpolate into the
//! lobes of any surface across a depth edge (a blend of two axes is a third direction, and
//! the exponential of an interpolated sharpness is not the interpolation of two
//! exponentials), the closed form then costs the working resolution's pixels rather than
//! the photo's, and both heads are compared on the same footing. At scale 1 (the default)
//! nothing is resampled and the closed form writes the view directly.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::depth::DepthMap;
use crate::engine::manifest::{
    self, LobeDomain, LobeSpec, ManifestError, Precision, Task, VerifiedModel, LOBE_LAYOUT,
};
use crate::engine::resample;
use crate::engine::{Engine, ModelSource, Plan, Tensor};
use crate::io::photo::SrgbImage;
use crate::reshade::{PreparedPhoto, ReshadeError, Reshader};
use crate::views::Intrinsics;

use super::models::{other_head, other_precisions};
use super::{disparity, is_residual, manifests_where, planar, round_up, NetError, NetOptions};

/// Channels of one lobe in the graph's output (mu_x, mu_y, mu_z, sharpness, amp_r, amp_g,
/// amp_b).
pub const PER_LOBE: usize = LOBE_LAYOUT.len();
/// model.DISPARITY_DEPTH: the disparity input is 0.25 / depth, so the pixel's point is
/// (0.25 / d)·r and c − X points along (d / 0.25)·c − r, finite for the sky (d = 0).
const DISPARITY_DEPTH: f32 = 0.25;
/// PyTorch's guard in view_directions: v / sqrt(|v|² + 1e-12).
const NORM_EPS: f32 = 1e-12;
/// Floats per pixel in [`LobeField`]: d/0.25, the ray (3), then per lobe μ (3), λ,
/// a (3) and the lobe's value towards the input camera, then (lobes-slide) ρ.
const GEOMETRY: usize = 4;
const PER_LOBE_STORED: usize = PER_LOBE + 1;
/// model.SLIDE_MIN_DEPTH_RATIO: the layer's point stays in front of a forward-moving camera.
const SLIDE_MIN_DEPTH_RATIO: f32 = 0.05;
/// model.LINEAR_GAMMA, LINEAR_FLOOR and CLIPPED: the linear-clamped domain's inverse tone
/// curve, the floor that keeps its slope finite, and the level a pixel counts as clipped at.
const LINEAR_GAMMA: f32 = 2.2;
const LINEAR_FLOOR: f32 = 1e-4;
const CLIPPED: f32 = 1.0 - 0.5 / 255.0;

fn is_lobes(task: Task) -> bool {
    task == Task::ReshadeLobes
}

/// Unit direction from a pixel's point towards the camera centre `c`: normalize(q·c − r)
/// with q = d / 0.25 (model.view_directions).
#[inline]
fn direction(q: f32, r: [f32; 3], c: [f32; 3]) -> [f32; 3] {
    let v = [q * c[0] - r[0], q * c[1] - r[1], q * c[2] - r[2]];
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + NORM_EPS).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// exp(λ (μ·w − 1)): one lobe seen along `w`.
#[inline]
fn lobe_value(mu: [f32; 3], sharpness: f32, w: [f32; 3]) -> f32 {
    (sharpness * (mu[0] * w[0] + mu[1] * w[1] + mu[2] * w[2] - 1.0)).exp()
}

/// Normalised image coordinates of the point at disparity ratio `z` along ray `r`, seen from
/// camera centre `c` (model.project_from).
#[inline]
fn project(z: f32, r: [f32; 3], c: [f32; 3]) -> [f32; 2] {
    let q = [r[0] - z * c[0], r[1] - z * c[1], r[2] - z * c[2]];
    let depth = q[2].max(SLIDE_MIN_DEPTH_RATIO);
    [q[0] / depth, q[1] / depth]
}

/// model.shrink: 0 where |x| <= t, x ∓ t beyond (written as PyTorch's two ReLUs).
#[inline]
fn shrink(x: f32, t: f32) -> f32 {
    if t == 0.0 {
        return x;
    }
    (x - t).max(0.0) - (-x - t).max(0.0)
}

/// Each pixel's ray K⁻¹[u, v, 1] at `width`×`height` for a photo taken with `camera`
/// (whose pixel i has its centre at i + 0.5), in three planes: the intrinsics scaled to
/// that size and moved to the network's convention of centres at integer coordinates,
/// cx' = cx·s − 0.5 (= (cx_opencv + 0.5)·s − 0.5). Computed in f32 like the toolchain's.
pub fn pixel_rays(camera: &Intrinsics, width: usize, height: usize) -> Vec<f32> {
    let sx = width as f64 / f64::from(camera.width);
    let sy = height as f64 / f64::from(camera.height);
    let (fx, fy) = ((camera.fx * sx) as f32, (camera.fy * sy) as f32);
    let (cx, cy) = ((camera.cx * sx - 0.5) as f32, (camera.cy * sy - 0.5) as f32);
    let plane = width * height;
    let mut rays = vec![1.0f32; 3 * plane];
    for y in 0..height {
        let ry = (y as f32 - cy) / fy;
        for x in 0..width {
            rays[y * width + x] = (x as f32 - cx) / fx;
            rays[plane + y * width + x] = ry;
        }
    }
    rays
}

/// Per-pixel lobes and geometry of one photo at the network's working resolution: all
/// that a view needs, with each lobe's value towards the input camera computed once.
#[derive(Clone, Debug)]
pub struct LobeField {
    width: usize,
    height: usize,
    spec: LobeSpec,
    /// [`GEOMETRY`] + K · [`PER_LOBE_STORED`] (+ 1 for ρ) floats per pixel, row-major.
    data: Vec<f32>,
    /// lobes-slide: the sliding layer S = photo · fraction, RGB per pixel; else empty.
    layer: Vec<f32>,
    /// Domain linear-clamped: the photo the lobes were computed for, RGB per pixel, and its
    /// linear light (photo^2.2, the same for every view); else empty.
    photo: Vec<f32>,
    linear: Vec<f32>,
    /// Pixels per unit of normalised coordinate, from the rays as PyTorch takes them.
    focal: [f32; 2],
}

impl LobeField {
    /// The field from the graph's output `lobes` (planar [C, H, W], padding cropped) and
    /// its inputs: `image` (planar [3, H, W]; a lobes-slide layer is a share of it), the
    /// disparity `disparity` ([H, W]) and the rays `rays` (planar [3, H, W]).
    pub fn new(
        spec: LobeSpec,
        width: usize,
        height: usize,
        lobes: &[f32],
        image: &[f32],
        disparity: &[f32],
        rays: &[f32],
    ) -> Result<Self, NetError> {
        let plane = width * height;
        let k = spec.lobes;
        for (name, len, planes) in [
            ("lobes", lobes.len(), spec.channels()),
            ("image", image.len(), 3),
            ("disparity", disparity.len(), 1),
            ("rays", rays.len(), 3),
        ] {
            if len != planes * plane {
                return Err(NetError::Input(format!(
                    "{name} holds {len} values; {planes} planes of {width}x{height} are {}",
                    planes * plane
                )));
            }
        }
        let stride = Self::stride(spec);
        let mut data = vec![0.0f32; stride * plane];
        for (i, px) in data.chunks_exact_mut(stride).enumerate() {
            let q = disparity[i] / DISPARITY_DEPTH;
            let r = [rays[i], rays[plane + i], rays[2 * plane + i]];
            px[..GEOMETRY].copy_from_slice(&[q, r[0], r[1], r[2]]);
            // The same function as every view's direction, at c = 0: a view from the input
            // camera gives these bits again, so its change is exactly zero.
            let w0 = direction(q, r, [0.0; 3]);
            for (j, l) in px[GEOMETRY..].chunks_exact_mut(PER_LOBE_STORED).enumerate() {
                let at = |c: usize| lobes[(PER_LOBE * j + c) * plane + i];
                for (c, v) in l[..PER_LOBE].iter_mut().enumerate() {
                    *v = at(c);
                }
                l[PER_LOBE] = lobe_value([l[0], l[1], l[2]], l[3], w0);
            }
        }
        let photo: Vec<f32> = if spec.domain == LobeDomain::LinearClamped {
            (0..3 * plane)
                .map(|j| image[(j % 3) * plane + j / 3])
                .collect()
        } else {
            Vec::new()
        };
        let linear = photo
            .iter()
            .map(|p| p.max(0.0).powf(LINEAR_GAMMA))
            .collect();
        let mut layer = Vec::new();
        if spec.slide {
            let extra = PER_LOBE * k;
            layer = vec![0.0f32; 3 * plane];
            for i in 0..plane {
                for c in 0..3 {
                    layer[3 * i + c] = image[c * plane + i] * lobes[(extra + c) * plane + i];
                }
                data[i * stride + stride - 1] = lobes[(extra + 3) * plane + i];
            }
        }
        // As model.slide_change: one over the rays' step between neighbouring pixels.
        let step = |a: usize, b: usize, len: usize| {
            if len > 1 {
                1.0 / (rays[b] - rays[a])
            } else {
                1.0
            }
        };
        let focal = [step(0, 1, width), step(plane, plane + width, height)];
        Ok(Self {
            width,
            height,
            spec,
            data,
            layer,
            photo,
            linear,
            focal,
        })
    }

    fn stride(spec: LobeSpec) -> usize {
        GEOMETRY + spec.lobes * PER_LOBE_STORED + usize::from(spec.slide)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn spec(&self) -> LobeSpec {
        self.spec
    }

    /// The thresholded change of pixel `i` for a camera at `c`.
    #[inline]
    fn change_at(&self, i: usize, c: [f32; 3]) -> [f32; 3] {
        let stride = Self::stride(self.spec);
        let px = &self.data[i * stride..][..stride];
        let r = [px[1], px[2], px[3]];
        let w = direction(px[0], r, c);
        let lobes = &px[GEOMETRY..GEOMETRY + self.spec.lobes * PER_LOBE_STORED];
        if self.spec.domain == LobeDomain::LinearClamped {
            return self.clamped_change(i, lobes, w);
        }
        let mut change = [0.0f32; 3];
        for l in lobes.chunks_exact(PER_LOBE_STORED) {
            let d = lobe_value([l[0], l[1], l[2]], l[3], w) - l[PER_LOBE];
            change[0] += l[4] * d;
            change[1] += l[5] * d;
            change[2] += l[6] * d;
        }
        if self.spec.slide {
            let moved = self.slid(i, px[0], px[stride - 1], r, c);
            for (ch, m) in change.iter_mut().zip(moved) {
                *ch += m;
            }
        }
        let t = self.spec.deadzone;
        change.map(|v| shrink(v, t))
    }

    /// The change of pixel `i` in the linear-clamped domain (see the module comment), as the
    /// display value it leads to less the photo's, for the lobes `lobes` seen along `w`.
    #[inline]
    fn clamped_change(&self, i: usize, lobes: &[f32], w: [f32; 3]) -> [f32; 3] {
        let (mut s, mut s0) = ([0.0f32; 3], [0.0f32; 3]);
        for l in lobes.chunks_exact(PER_LOBE_STORED) {
            let g = lobe_value([l[0], l[1], l[2]], l[3], w);
            for ch in 0..3 {
                s[ch] += l[4 + ch] * g;
                s0[ch] += l[4 + ch] * l[PER_LOBE];
            }
        }
        let t = self.spec.deadzone;
        std::array::from_fn(|ch| {
            let (photo, linear) = (self.photo[3 * i + ch], self.linear[3 * i + ch]);
            let clipped = photo >= CLIPPED;
            let (k, dug) = if clipped {
                (1.0, (s0[ch] - linear).max(0.0))
            } else {
                ((linear / s0[ch].max(1e-12)).min(1.0), 0.0)
            };
            let moved = (linear + k * (s[ch] - s0[ch]) + dug).min(1.0);
            let change = shrink(moved - linear, t);
            if change == 0.0 {
                0.0
            } else {
                (linear + change).max(LINEAR_FLOOR).powf(1.0 / LINEAR_GAMMA) - photo
            }
        })
    }

    /// The sliding layer's change at pixel `i` (disparity ratio `q`, layer depth share `rho`,
    /// ray `r`) for a camera at `c`: the layer sampled from where its parallax brings it,
    /// less the layer there (model.slide_change, grid_sample bilinear with border padding).
    #[inline]
    fn slid(&self, i: usize, q: f32, rho: f32, r: [f32; 3], c: [f32; 3]) -> [f32; 3] {
        let layer = project(q * (1.0 - rho), r, c);
        let surface = project(q, r, c);
        let (w, h) = (self.width, self.height);
        let x = (i % w) as f32 - (layer[0] - surface[0]) * self.focal[0];
        let y = (i / w) as f32 - (layer[1] - surface[1]) * self.focal[1];
        let x = if x.is_nan() {
            0.0
        } else {
            x.clamp(0.0, (w - 1) as f32)
        };
        let y = if y.is_nan() {
            0.0
        } else {
            y.clamp(0.0, (h - 1) as f32)
        };
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let at = |xx: usize, yy: usize, ch: usize| self.layer[3 * (yy * w + xx) + ch];
        std::array::from_fn(|ch| {
            let top = at(x0, y0, ch) * (1.0 - fx) + at(x1, y0, ch) * fx;
            let bottom = at(x0, y1, ch) * (1.0 - fx) + at(x1, y1, ch) * fx;
            top * (1.0 - fy) + bottom * fy - self.layer[3 * i + ch]
        })
    }

    /// The thresholded change for a camera at `centre`, interleaved RGB per pixel, computed
    /// on `threads` threads (bands of rows).
    pub fn change(&self, centre: [f64; 3], threads: usize) -> Vec<f32> {
        let c = centre.map(|v| v as f32);
        let mut out = vec![0.0f32; 3 * self.width * self.height];
        crate::parallel::bands(
            threads,
            self.height,
            3 * self.width,
            &mut out,
            |y0, rows| {
                for (j, px) in rows.chunks_exact_mut(3).enumerate() {
                    px.copy_from_slice(&self.change_at(y0 * self.width + j, c));
                }
            },
        );
        out
    }

    /// `photo` (of the field's size) plus the change for a camera at `centre`, clamped to
    /// [0, 1], on `threads` threads.
    pub fn reshade(
        &self,
        photo: &SrgbImage,
        centre: [f64; 3],
        threads: usize,
    ) -> Result<SrgbImage, NetError> {
        let (w, h) = (photo.width() as usize, photo.height() as usize);
        if (w, h) != (self.width, self.height) {
            return Err(NetError::Input(format!(
                "the photo is {w}x{h} but the lobes are {}x{}",
                self.width, self.height
            )));
        }
        let c = centre.map(|v| v as f32);
        let src = photo.data();
        let mut rgb = vec![0.0f32; 3 * w * h];
        crate::parallel::bands(threads, h, 3 * w, &mut rgb, |y0, rows| {
            let base = y0 * w;
            for (j, px) in rows.chunks_exact_mut(3).enumerate() {
                let i = base + j;
                let change = self.change_at(i, c);
                for ch in 0..3 {
                    px[ch] = (src[3 * i + ch] + change[ch]).clamp(0.0, 1.0);
                }
            }
        });
        Ok(image_from_rgb(w, h, rgb))
    }
}

fn image_from_rgb(w: usize, h: usize, rgb: Vec<f32>) -> SrgbImage {
    let buffer =
        image::Rgb32FImage::from_raw(w as u32, h as u32, rgb).expect("buffer matches size");
    SrgbImage::from_rgb32f(buffer)
}

/// The lobe-head reshading model: its graph, the engine that runs it once per photo, and
/// the threads the per-view closed form uses (the engine's).
pub struct LobeReshader {
    model: Box<VerifiedModel>,
    spec: LobeSpec,
    engine: Arc<dyn Engine>,
    options: NetOptions,
    multiple: usize,
    plans: Mutex<HashMap<(usize, usize), Arc<dyn Plan>>>,
}

impl LobeReshader {
    /// Loads the lobe-head model at `path`: its manifest (task `reshade-lobes`), or a
    /// directory holding exactly one at `precision`. Of the options, `scale` (working
    /// resolution) applies, and `max_offset` when given: unlike the residual head, the
    /// closed form is defined for any camera, so offsets are not shortened to the trained
    /// range unless asked. Key views, batches and parallel views are for per-view network
    /// runs, which this head has none of.
    pub fn load(
        path: &Path,
        precision: Precision,
        engine: Arc<dyn Engine>,
        options: NetOptions,
    ) -> Result<Self, NetError> {
        options.check()?;
        let model = if path.is_dir() {
            find_in_dir(path, precision)?
        } else {
            let m = manifest::Manifest::load(path)?;
            if m.task != Task::ReshadeLobes {
                return Err(NetError::Model {
                    path: path.to_owned(),
                    problem: format!(
                        "is a {:?} manifest (the residual head), not a lobe-head one (\"reshade-lobes\"): drop --head lobes or pass a -lobes manifest",
                        m.task.to_string()
                    ),
                });
            }
            verified(path, precision)?
        };
        let spec = manifest::lobe_spec(&model.manifest_path, &model.manifest)?;
        let defaults = NetOptions::default();
        if options.key_views != defaults.key_views
            || options.batch != defaults.batch
            || options.parallel_views != defaults.parallel_views
        {
            log::warn!(
                "{}: the lobe head runs its network once per photo; key views, batches and parallel views do not apply",
                model.manifest.name
            );
        }
        Ok(Self {
            multiple: model.manifest.size_multiple as usize,
            model: Box::new(model),
            spec,
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

    pub fn spec(&self) -> LobeSpec {
        self.spec
    }

    pub fn manifest(&self) -> &manifest::Manifest {
        &self.model.manifest
    }

    /// Threads of the per-view closed form (the engine's).
    pub fn threads(&self) -> usize {
        self.engine.threads().max(1)
    }

    fn plan(&self, pw: usize, ph: usize) -> Result<Arc<dyn Plan>, NetError> {
        let mut plans = self.plans.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(plan) = plans.get(&(pw, ph)) {
            return Ok(plan.clone());
        }
        let m = &self.model;
        let sig = manifest::signature(Task::ReshadeLobes).expect("lobes signature");
        let started = std::time::Instant::now();
        let shapes: Vec<(&str, Vec<usize>)> = vec![
            ("image", vec![1, 3, ph, pw]),
            ("disparity", vec![1, 1, ph, pw]),
            ("rays", vec![1, 3, ph, pw]),
        ];
        let plan = self.engine.plan(
            ModelSource {
                path: &m.model_path,
                bytes: &m.bytes,
                precision: m.manifest.precision,
            },
            &shapes,
            sig.outputs,
        )?;
        log::info!(
            "{}: {} plan for {pw}x{ph} ready in {:.0} ms",
            m.manifest.name,
            self.engine.name(),
            started.elapsed().as_secs_f64() * 1e3
        );
        plans.insert((pw, ph), plan.clone());
        Ok(plan)
    }

    /// Runs the network once for `image` (taken with `camera`) and its depth (training
    /// units): the photo ready to be reshaded for any number of views.
    pub fn prepare_photo<'a>(
        &'a self,
        image: &'a SrgbImage,
        depth: &DepthMap,
        camera: &Intrinsics,
    ) -> Result<LobePhoto<'a>, NetError> {
        let (w, h) = (image.width() as usize, image.height() as usize);
        if w == 0 || h == 0 {
            return Err(NetError::Input(format!(
                "the photo is {w}x{h}: nothing to reshade"
            )));
        }
        if depth.width() != w || depth.height() != h {
            return Err(NetError::Input(format!(
                "depth is {}x{} but the photo is {w}x{h}",
                depth.width(),
                depth.height()
            )));
        }
        if (camera.width as usize, camera.height as usize) != (w, h) {
            return Err(NetError::Input(format!(
                "the camera intrinsics are for {}x{} but the photo is {w}x{h}",
                camera.width, camera.height
            )));
        }
        if !(camera.fx > 0.0 && camera.fy > 0.0 && camera.cx.is_finite() && camera.cy.is_finite()) {
            return Err(NetError::Input(format!(
                "the camera intrinsics (fx {}, fy {}, principal point {}, {}) need finite fx, \
                 fy > 0 and a finite principal point",
                camera.fx, camera.fy, camera.cx, camera.cy
            )));
        }
        let (ww, wh) = self.options.working_size(w, h);
        let (pw, ph) = (round_up(ww, self.multiple), round_up(wh, self.multiple));
        let full_disparity: Vec<f32> = depth.data().iter().map(|&z| disparity(z)).collect();
        let (work, work_disparity) = if (ww, wh) == (w, h) {
            (planar(image), full_disparity)
        } else {
            (
                resample::resize(&planar(image), w, h, ww, wh),
                resample::resize(&full_disparity, w, h, ww, wh),
            )
        };
        let rays = pixel_rays(camera, ww, wh);
        let pad = |src: &[f32], planes: usize| {
            Tensor::new(
                vec![1, planes, ph, pw],
                resample::pad_replicate(src, ww, wh, pw, ph),
            )
        };
        let (image_t, disparity_t, rays_t) =
            (pad(&work, 3), pad(&work_disparity, 1), pad(&rays, 3));
        let plan = self.plan(pw, ph)?;
        let outputs = plan.run(&[
            ("image", &image_t),
            ("disparity", &disparity_t),
            ("rays", &rays_t),
        ])?;
        let expected = vec![1, self.spec.channels(), ph, pw];
        let lobes = match outputs.into_iter().next() {
            Some(t) if t.shape == expected => t,
            other => {
                return Err(NetError::Model {
                    path: self.model.model_path.clone(),
                    problem: format!(
                        "gives \"lobes\" of shape {:?}; its manifest {} says {} lobes ({} channels), so {expected:?} at this size",
                        other.map(|t| t.shape),
                        self.model.manifest_path.display(),
                        self.spec.lobes,
                        self.spec.channels(),
                    ),
                })
            }
        };
        let lobes = resample::crop(&lobes.data, pw, ph, ww, wh);
        let field = LobeField::new(self.spec, ww, wh, &lobes, &work, &work_disparity, &rays)?;
        Ok(LobePhoto {
            net: self,
            image,
            size: (w, h),
            padded: (pw, ph),
            field,
        })
    }

    /// A camera centre as the closed form gets it: shortened to `max_offset` when one
    /// was given, else unchanged.
    fn limit_offset(&self, centre: [f64; 3]) -> [f64; 3] {
        let Some(max) = self.options.max_offset else {
            return centre;
        };
        let len = centre.iter().map(|c| c * c).sum::<f64>().sqrt();
        if len > max {
            centre.map(|c| c * max / len)
        } else {
            centre
        }
    }
}

impl Reshader for LobeReshader {
    fn description(&self) -> String {
        let m = &self.model.manifest;
        let o = &self.options;
        let sha: String = m.sha256.trim().chars().take(12).collect();
        format!(
            "{} {} ({}, head {}: {} lobes in the {} domain, dead zone {}, graph {sha}, engine {} x{} threads once per photo at scale {}, longest side {}; closed form per view on {} threads{})",
            m.name,
            m.version,
            m.precision,
            self.spec.head(),
            self.spec.lobes,
            self.spec.domain.name(),
            self.spec.deadzone,
            self.engine.name(),
            self.engine.threads(),
            o.scale,
            o.max_side.map_or("unlimited".into(), |m| format!("{m} px")),
            self.threads(),
            o.max_offset
                .map_or(String::new(), |d| format!(", offsets limited to {d}")),
        )
    }

    fn prepare<'a>(
        &'a self,
        image: &'a SrgbImage,
        depth: &'a DepthMap,
        camera: &Intrinsics,
    ) -> Result<Box<dyn PreparedPhoto + 'a>, ReshadeError> {
        Ok(Box::new(self.prepare_photo(image, depth, camera)?))
    }
}

/// A photo after the lobe network: reshaded per view by the closed form alone.
pub struct LobePhoto<'a> {
    net: &'a LobeReshader,
    image: &'a SrgbImage,
    size: (usize, usize),
    padded: (usize, usize),
    field: LobeField,
}

impl LobePhoto<'_> {
    /// The photo reshaded for a camera at `centre` (input camera frame, training units).
    pub fn reshade_view(&self, centre: [f64; 3]) -> Result<SrgbImage, NetError> {
        let centre = self.net.limit_offset(centre);
        let threads = self.net.threads();
        let (w, h) = self.size;
        let (ww, wh) = (self.field.width, self.field.height);
        if (ww, wh) == (w, h) {
            return self.field.reshade(self.image, centre, threads);
        }
        // Reduced working resolution: the change (not the lobes) goes up to the photo's
        // size, as the residual head's residual does (see the module comment).
        let change = self.field.change(centre, threads);
        let plane = ww * wh;
        let mut planes = vec![0.0f32; 3 * plane];
        for (i, px) in change.chunks_exact(3).enumerate() {
            for c in 0..3 {
                planes[c * plane + i] = px[c];
            }
        }
        let up = resample::resize(&planes, ww, wh, w, h);
        let full = w * h;
        let src = self.image.data();
        let mut rgb = vec![0.0f32; 3 * full];
        for (i, px) in rgb.chunks_exact_mut(3).enumerate() {
            for c in 0..3 {
                px[c] = (src[3 * i + c] + up[c * full + i]).clamp(0.0, 1.0);
            }
        }
        Ok(image_from_rgb(w, h, rgb))
    }

    /// The per-pixel lobes and geometry at the working resolution.
    pub fn field(&self) -> &LobeField {
        &self.field
    }

    /// The padded working-resolution size the network ran at.
    pub fn network_size(&self) -> (usize, usize) {
        self.padded
    }
}

impl PreparedPhoto for LobePhoto<'_> {
    fn reshade(&self, centre: [f64; 3]) -> Result<SrgbImage, ReshadeError> {
        Ok(self.reshade_view(centre)?)
    }
}

fn verified(path: &Path, precision: Precision) -> Result<VerifiedModel, NetError> {
    let model = manifest::load_verified(path)?;
    manifest::check_reshade(path, &model.manifest, Task::ReshadeLobes, precision)?;
    Ok(model)
}

fn find_in_dir(dir: &Path, precision: Precision) -> Result<VerifiedModel, NetError> {
    let found = manifests_where(dir, Some(precision), is_lobes)?;
    match found.as_slice() {
        [(one, _)] => verified(one, precision),
        [] => Err(NetError::Model {
            path: dir.to_owned(),
            problem: format!(
                "holds no lobe-head (\"reshade-lobes\") manifest with precision {precision}{}{}",
                other_precisions(dir, precision, is_lobes),
                other_head(dir, is_residual, "residual"),
            ),
        }),
        many => {
            let list: Vec<_> = many.iter().map(|(p, _)| p).collect();
            Err(NetError::Model {
                path: dir.to_owned(),
                problem: format!(
                    "holds several {precision} lobe-head manifests: {list:?}; pass one manifest with --model"
                ),
            })
        }
    }
}

/// Whether `dir` holds lobe-head manifests (any precision) and residual-head ones.
pub fn heads_in(dir: &Path) -> Result<(bool, bool), ManifestError> {
    let any = |wanted: fn(Task) -> bool| -> Result<bool, ManifestError> {
        match manifests_where(dir, None, wanted) {
            Ok(found) => Ok(!found.is_empty()),
            Err(NetError::Manifest(e)) => Err(e),
            Err(_) => Ok(false),
        }
    };
    Ok((any(is_lobes)?, any(is_residual)?))
}

#[cfg(test)]
mod tests;
