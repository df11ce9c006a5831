//! Relocation with a layered depth image (LDI), after 3D Photo / 3D Moments.
//!
//! **Build, once per photo** ([`Ldi::build`]): depth discontinuities are found on
//! disparity (`edges`), the mesh is cut there, and behind every occluding edge a
//! background layer is grown as wide as the widest view can see behind it and inpainted
//! in depth and colour from the background side only (`band`). Every sample becomes
//! a quad whose corners it shares with the samples of its surface (`mesh`).
//!
//! **Render, per view** ([`Ldi::render`]): project the corners with the view's off-axis
//! camera, rasterise the quads into a supersampled z-buffer, fill whatever is still
//! uncovered from the far side, and resolve colours: original pixels take the colour of
//! the view's (reshaded) image, band samples the colour of the pixel they were
//! inpainted from, also in the view's image. Everything but the projection and the
//! rasterisation is done at build time.

mod band;
mod edges;
mod fill;
mod matte;
mod mesh;
mod render;

use crate::depth::DepthMap;
use crate::io::photo::{byte, SrgbImage};
use crate::relocate::map::{ViewMap, NO_SOURCE};
use crate::relocate::{check_sizes, PreparedRelocation, RelocateError, Relocator};
use crate::views::{Intrinsics, ViewCamera};
use image::RgbImage;

use mesh::Side;
use render::Origin;

/// A small deterministic generator for the patch synthesis's random candidates (the band
/// and the view fill): the same photo gives the same views on every run.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// An offset drawn in the square of half-width `radius` (x first, then y).
    fn offset(&mut self, radius: i64) -> (i64, i64) {
        let span = (2 * radius + 1) as u64;
        let dx = (self.next() % span) as i64 - radius;
        let dy = (self.next() % span) as i64 - radius;
        (dx, dy)
    }
}

/// What the view shows beyond the photo's borders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Border {
    /// The border pixels are stretched outwards far enough that no view sees past them;
    /// the framing of the zero-parallax plane is exactly the input's.
    Extend,
    /// Every view is magnified about its centre by the same factor, just enough that
    /// the border never enters the frame of any view served ([`Ldi::fit_frame`]);
    /// nothing is invented or stretched, the framing is slightly tighter where the
    /// photo's edges would otherwise show. The runtime's default.
    #[default]
    Crop,
    /// The framing is the input's and what a view sees beyond the photo's edge is
    /// filled like any other uncovered region, from the background beside it.
    Inpaint,
}

impl crate::io::keyword::Keyword for Border {
    const ALL: &'static [(Self, &'static str)] = &[
        (Border::Extend, "extend"),
        (Border::Crop, "crop"),
        (Border::Inpaint, "inpaint"),
    ];
}

/// The name `--border` takes.
impl std::fmt::Display for Border {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(crate::io::keyword::Keyword::keyword(*self))
    }
}

/// The runtime's [`LdiConfig::band_smoothing`]: 3 px scored within 0.1 dB of 2 and 4 px
/// on held-out renders at 128 and 640 px wide, and blurs the band's texture less than
/// wider boxes (docs/relocation.md).
pub const BAND_SMOOTHING_PX: usize = 3;

/// Where the inpainted background behind occluders takes its colours from in a view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BandColours {
    /// From the view's own (reshaded) image, at the pixel each band sample was
    /// inpainted from: the hidden background is shaded like the visible background.
    View,
    /// The colours inpainted at build time, the same in every view.
    Inpainted,
}

/// How the pixels that mix the two sides of a depth step are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Silhouettes {
    /// The foreground share of the pixels either side of a cut moves with the
    /// foreground, over what each view sees behind it (see [`matte`]): no rim of the
    /// photo's background moves with the object, no ghost of it stays behind. The
    /// runtime's default.
    #[default]
    Soft,
    /// Every pixel belongs wholly to its side of the cut.
    Hard,
}

impl crate::io::keyword::Keyword for Silhouettes {
    const ALL: &'static [(Self, &'static str)] =
        &[(Silhouettes::Soft, "soft"), (Silhouettes::Hard, "hard")];
}

impl std::fmt::Display for Silhouettes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(crate::io::keyword::Keyword::keyword(*self))
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct LdiConfig {
    /// A step between neighbouring pixels is a discontinuity when it exceeds this
    /// fraction of the pair's larger disparity (and the local slope does not explain it).
    pub edge_threshold: f32,
    /// Band samples join a neighbouring surface when their disparities differ by less
    /// than this fraction.
    pub link_threshold: f32,
    /// Contours with fewer edge pixels are noise and are not cut.
    pub min_contour_px: usize,
    /// Upper bound on the band width and border margin, in build pixels.
    pub max_band_px: usize,
    /// Patch half-size of the colour inpainting.
    pub patch_radius: usize,
    /// Random background candidates per band pixel, besides the coherent ones.
    pub random_candidates: usize,
    /// Subsamples per output pixel along each axis (anti-aliasing).
    pub supersampling: usize,
    pub border: Border,
    pub band_colours: BandColours,
    /// Radius in build pixels of the box over which the band's copied colours are
    /// averaged with the surface around them (0: the copies as synthesised).
    pub band_smoothing: usize,
    pub silhouettes: Silhouettes,
}

impl Default for LdiConfig {
    fn default() -> Self {
        Self {
            edge_threshold: 0.04,
            link_threshold: 0.08,
            min_contour_px: 6,
            max_band_px: 256,
            patch_radius: 2,
            random_candidates: 6,
            supersampling: 2,
            // The builder's own default keeps the input's framing; the runtime
            // (`RelocateConfig`) crops.
            border: Border::Extend,
            band_colours: BandColours::View,
            band_smoothing: BAND_SMOOTHING_PX,
            silhouettes: Silhouettes::Soft,
        }
    }
}

/// Numbers about one build, for logs and benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct LdiStats {
    pub width: usize,
    pub height: usize,
    pub contours_kept: usize,
    pub contours_dropped: usize,
    pub cut_pairs: usize,
    pub band_samples: usize,
    /// Pixels either side of cuts drawn with partial coverage (soft silhouettes).
    pub soft_pixels: usize,
    pub vertices: usize,
    /// Heap bytes the built LDI keeps (per-view buffers not included).
    pub memory_bytes: usize,
    /// The offset the band and border margin were sized for, scene units.
    pub reach: f64,
    pub border_margin_px: f64,
    /// With crop framing, how much every view is magnified about its centre (1 without).
    pub crop: f64,
}

/// A built layered depth image of one photo.
pub struct Ldi {
    source: Intrinsics,
    /// Depth units per mesh unit: the mesh holds depth divided by this power of two
    /// near the nearest depth, so that any depth scale (micrometres to light years)
    /// meets the same floating-point ranges and thresholds; cameras are divided by it
    /// too, which leaves every projection unchanged.
    scale: f64,
    mesh: mesh::Mesh,
    mattes: matte::Mattes,
    border: Border,
    supersampling: usize,
    /// Build-time colours of the band samples, with [`BandColours::Inpainted`].
    band_rgb: Option<Vec<[f32; 3]>>,
    /// Per band sample, what [`LdiConfig::band_smoothing`] adds to the colour it copies
    /// from each view (empty without smoothing or with build-time colours).
    band_shade: Vec<[f32; 3]>,
    stats: LdiStats,
}

/// A rendered view with, per output pixel, the fraction of it showing original pixels
/// (rather than inpainted background) and the fraction no quad covered (filled from
/// the far side after rasterisation).
pub struct Rendered {
    pub image: SrgbImage,
    pub front_fraction: Vec<f32>,
    pub hole_fraction: Vec<f32>,
}

/// The farthest a view at `view`'s centre can see behind an edge, expressed as an
/// equivalent sideways offset: tz moves points radially by up to half the image
/// diagonal's worth of pixels per unit disparity.
pub fn view_reach(centre: [f64; 3], source: &Intrinsics) -> f64 {
    let sideways = centre[0].hypot(centre[1]);
    let half_diagonal = f64::from(source.width).hypot(f64::from(source.height)) / 2.0;
    sideways + centre[2].abs() * half_diagonal / source.fx.min(source.fy)
}

/// The widest parallax between the photo's nearest and farthest points at
/// `px_per_disparity`, in pixels (at most the band's width), plus one: how far a view
/// may see past the frame's edge.
fn border_margin(disparity: &[f32], px_per_disparity: f64, max_band_px: usize) -> f64 {
    let (lo, hi) = disparity
        .iter()
        .fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        });
    (px_per_disparity * f64::from(hi - lo))
        .ceil()
        .min(max_band_px as f64)
        + 1.0
}

/// The band's smoothing, as per-sample offsets each view adds to its own colours; with
/// [`BandColours::Inpainted`], the band's colours fixed at build time instead, which
/// already hold the smoothing (the offsets are then empty).
fn band_colours(
    band: &band::Band,
    input: &band::BandInput,
    mattes: &matte::Mattes,
    colours: &SrgbImage,
    config: &LdiConfig,
) -> (Vec<[f32; 3]>, Option<Vec<[f32; 3]>>) {
    let (w, h) = (input.width, input.height);
    let mut shade = band::smoothing(band, input, config.band_smoothing);
    // A soft pixel trades the colour beneath it for what each view sees behind it:
    // that colour must be the one mixed into the photo's pixel, not the mean.
    for soft in &mattes.soft {
        let beneath = (soft.beneath as usize).checked_sub(w * h);
        if let Some(offset) = beneath.and_then(|k| shade.get_mut(k)) {
            *offset = [0.0; 3];
        }
    }
    if config.band_colours != BandColours::Inpainted {
        return (shade, None);
    }
    let rgb = band
        .source
        .iter()
        .enumerate()
        .map(|(k, &i)| shaded(colours.get(i % w as u32, i / w as u32), shade.get(k)))
        .collect();
    (Vec::new(), Some(rgb))
}

impl Ldi {
    /// Builds the LDI of a photo: `colours` guide the inpainting (each view's own
    /// colours are used when rendering), `reach` is the largest view offset to serve
    /// (see [`view_reach`]).
    pub fn build(
        colours: &SrgbImage,
        depth: &DepthMap,
        source: &Intrinsics,
        config: &LdiConfig,
        reach: f64,
    ) -> Result<Self, RelocateError> {
        check_sizes(colours, depth, source)?;
        let (w, h) = (depth.width(), depth.height());
        let scale = mesh_scale(depth.data());
        let unit = scale as f32;
        let disparity: Vec<f32> = depth.data().iter().map(|&z| (unit / z).max(1e-6)).collect();
        let reach_units = reach / scale;
        let cuts = edges::detect(
            &disparity,
            w,
            h,
            config.edge_threshold,
            config.min_contour_px,
        );
        let f = source.fx.max(source.fy);
        let band_input = band::BandInput {
            width: w,
            height: h,
            disparity: &disparity,
            colours: colours.data(),
            cuts: &cuts,
            px_per_disparity: f * reach_units,
            max_band_px: config.max_band_px,
            threshold: config.edge_threshold,
            patch_radius: config.patch_radius,
            random_candidates: config.random_candidates,
        };
        let mut band = band::grow(&band_input);
        let (mut mattes, fringes) = match config.silhouettes {
            Silhouettes::Soft => matte::estimate(colours.data(), &disparity, &cuts, &mut band, w),
            Silhouettes::Hard => (matte::Mattes::default(), Vec::new()),
        };
        let margin = border_margin(&disparity, f * reach_units, config.max_band_px);
        let ray = |u: f64, v: f64| {
            [
                ((u - source.cx) / source.fx) as f32,
                ((v - source.cy) / source.fy) as f32,
            ]
        };
        let mut mesh = mesh::build(&mesh::MeshInput {
            width: w,
            height: h,
            disparity: &disparity,
            cuts: &cuts,
            band: &band,
            link_threshold: config.link_threshold,
            ray: &ray,
            border_margin: if config.border == Border::Extend {
                margin
            } else {
                0.0
            },
        });
        matte::add_fringes(&mut mesh, &mut mattes, &fringes, w, &ray);
        let (band_shade, band_rgb) = band_colours(&band, &band_input, &mattes, colours, config);
        let stats = LdiStats {
            width: w,
            height: h,
            contours_kept: cuts.contours_kept,
            contours_dropped: cuts.contours_dropped,
            cut_pairs: cuts.pairs(&disparity).count(),
            band_samples: band.disparity.len(),
            soft_pixels: mattes.soft.len(),
            vertices: mesh.vertices.len(),
            memory_bytes: mesh.vertices.capacity() * std::mem::size_of::<mesh::Vertex>()
                + mesh.samples.capacity() * std::mem::size_of::<mesh::Sample>()
                + mattes.heap_bytes()
                + (band_shade.capacity() + band_rgb.as_ref().map_or(0, Vec::capacity))
                    * std::mem::size_of::<[f32; 3]>(),
            reach,
            border_margin_px: margin,
            crop: if config.border == Border::Crop {
                crop_for_margin(margin, source)
            } else {
                1.0
            },
        };
        log::info!(
            "LDI built: {}x{}, {} contours cut ({} dropped), {} vertices, {} in the \
             background band, {} soft, {}, border margin {} px",
            stats.width,
            stats.height,
            stats.contours_kept,
            stats.contours_dropped,
            stats.vertices,
            stats.band_samples,
            stats.soft_pixels,
            crate::io::limits::Bytes(stats.memory_bytes as u64),
            stats.border_margin_px
        );
        Ok(Self {
            source: *source,
            scale,
            mesh,
            mattes,
            border: config.border,
            supersampling: config.supersampling.max(1),
            band_rgb,
            band_shade,
            stats,
        })
    }

    pub fn stats(&self) -> LdiStats {
        self.stats
    }

    /// The view seen by `view`, with `colours` (the view's reshaded image, in the build
    /// camera's frame) on the original pixels.
    pub fn render(
        &self,
        colours: &SrgbImage,
        view: &ViewCamera,
    ) -> Result<SrgbImage, RelocateError> {
        if self.border == Border::Inpaint {
            return Ok(self.render_detailed(colours, view)?.image);
        }
        self.check_colours(colours)?;
        let frame = self.rasterise(view, false);
        Ok(self.resolve(&frame, colours))
    }

    /// [`Ldi::render`] rounded to 8 bits, without the float image in between.
    pub fn render_rgb8(
        &self,
        colours: &SrgbImage,
        view: &ViewCamera,
    ) -> Result<RgbImage, RelocateError> {
        if self.border == Border::Inpaint {
            return Ok(self.render_detailed(colours, view)?.image.to_rgb8());
        }
        self.check_colours(colours)?;
        let frame = self.rasterise(view, false);
        let (ow, oh) = (frame.width / frame.factor, frame.height / frame.factor);
        let mut bytes = vec![0u8; ow * oh * 3];
        let rows = bytes.chunks_exact_mut(ow * 3);
        self.resolve_rows(&frame, colours, rows, |out, rgb| {
            for (b, &v) in out.iter_mut().zip(rgb) {
                *b = byte(v);
            }
        });
        Ok(RgbImage::from_raw(ow as u32, oh as u32, bytes).expect("buffer matches size"))
    }

    /// The view with the fractions of each pixel that show original pixels and holes
    /// (the evaluation's regions, and where `--border inpaint` synthesises).
    pub fn render_detailed(
        &self,
        colours: &SrgbImage,
        view: &ViewCamera,
    ) -> Result<Rendered, RelocateError> {
        self.check_colours(colours)?;
        let frame = self.rasterise(view, true);
        let (front_fraction, hole_fraction) = fractions(&frame);
        let mut rendered = Rendered {
            image: self.resolve(&frame, colours),
            front_fraction,
            hole_fraction,
        };
        if self.border == Border::Inpaint {
            synthesize_holes(&mut rendered, &frame);
        }
        Ok(rendered)
    }

    fn check_colours(&self, colours: &SrgbImage) -> Result<(), RelocateError> {
        let (w, h) = (self.stats.width, self.stats.height);
        if (colours.width() as usize, colours.height() as usize) != (w, h) {
            return Err(RelocateError::SizeMismatch {
                colour_w: colours.width(),
                colour_h: colours.height(),
                depth_w: w,
                depth_h: h,
                camera_w: self.source.width,
                camera_h: self.source.height,
            });
        }
        Ok(())
    }

    /// Rasterises the mesh for `view`; `origins` asks for where each subsample's colour
    /// came from, which only the detailed render reads.
    fn rasterise(&self, view: &ViewCamera, origins: bool) -> render::Frame {
        let k = self.supersampling;
        let intrinsics = supersampled(&self.framed(&view.intrinsics), k);
        let centre = view.centre.map(|c| c / self.scale);
        let front_samples = self.stats.width * self.stats.height;
        render::rasterise(
            &self.mesh,
            &self.mattes,
            front_samples,
            centre,
            &intrinsics,
            k,
            origins,
        )
    }

    /// The view as a lookup into the colours: each pixel's subsamples' source pixels.
    /// None with `--border inpaint` (holes are synthesised per view), build-time band
    /// colours (not in the colours rendered), a smoothed band (a copy plus an offset) or
    /// soft silhouettes (a blend of three pixels, not a lookup).
    pub fn view_map(&self, view: &ViewCamera) -> Option<ViewMap> {
        if self.border == Border::Inpaint
            || self.band_rgb.is_some()
            || !self.band_shade.is_empty()
            || !self.mattes.is_empty()
        {
            return None;
        }
        let frame = self.rasterise(view, false);
        let k = frame.factor;
        let (ow, oh) = (frame.width / k, frame.height / k);
        let mut sources = Vec::with_capacity(frame.sample.len());
        for y in 0..oh {
            for x in 0..ow {
                for sy in 0..k {
                    let row = (y * k + sy) * frame.width + x * k;
                    sources.extend(frame.sample[row..row + k].iter().map(|&s| match s {
                        render::EMPTY => NO_SOURCE,
                        s => self.mesh.samples[s as usize].colour_from,
                    }));
                }
            }
        }
        let source = (self.stats.width as u32, self.stats.height as u32);
        Some(ViewMap::new(
            (ow as u32, oh as u32),
            source,
            k * k,
            &sources,
        ))
    }

    /// Tightens crop framing to the views that will be rendered: the smallest
    /// magnification at which none of them sees past the photo's outline (at most
    /// [`MAX_CROP`]). The framing [`Ldi::build`] sets serves any view within its reach
    /// and any focus within the photo's depths, which is more than most sets of views
    /// need (a focus plane amid the depths halves it).
    pub fn fit_frame(&mut self, views: &[ViewCamera]) {
        if self.border != Border::Crop || views.is_empty() {
            return;
        }
        let needed = views
            .iter()
            .map(|view| self.crop_for_view(view))
            .fold(1.0, f64::max);
        log::info!(
            "crop framing fitted to {} views: magnification {:.4} (for any focus {:.4})",
            views.len(),
            needed,
            self.stats.crop
        );
        self.stats.crop = needed;
    }

    /// The magnification at which `view` sees no further than the photo's outline.
    fn crop_for_view(&self, view: &ViewCamera) -> f64 {
        let centre = view.centre.map(|c| c / self.scale);
        let k = &view.intrinsics;
        let (hw, hh) = (f64::from(k.width) / 2.0, f64::from(k.height) / 2.0);
        let mut s = 1.0f64;
        for &(v, side) in &self.mesh.outline {
            let vertex = &self.mesh.vertices[v as usize];
            let Some([x, y, _]) = render::project_vertex(vertex, centre, k) else {
                return MAX_CROP;
            };
            let (x, y) = (f64::from(x), f64::from(y));
            // How far inside the frame the outline lies on its side, and that side's
            // distance from the centre the magnification is about.
            let (inside, half) = match side {
                Side::Left => (x, hw),
                Side::Right => (2.0 * hw - x, hw),
                Side::Top => (y, hh),
                Side::Bottom => (2.0 * hh - y, hh),
            };
            if inside >= half {
                return MAX_CROP;
            }
            s = s.max(half / (half - inside));
        }
        s.min(MAX_CROP)
    }

    /// The view's intrinsics, magnified about the image centre in crop mode.
    fn framed(&self, k: &Intrinsics) -> Intrinsics {
        if self.border != Border::Crop {
            return *k;
        }
        let (w, h) = (f64::from(k.width), f64::from(k.height));
        let s = self.stats.crop;
        Intrinsics {
            fx: k.fx * s,
            fy: k.fy * s,
            cx: (k.cx - w / 2.0) * s + w / 2.0,
            cy: (k.cy - h / 2.0) * s + h / 2.0,
            ..*k
        }
    }

    /// Averages each output pixel's subsamples, looking up every sample's colour, a
    /// row of subsamples at a time.
    fn resolve(&self, frame: &render::Frame, colours: &SrgbImage) -> SrgbImage {
        let (ow, oh) = (frame.width / frame.factor, frame.height / frame.factor);
        let mut rgb = vec![0.0f32; ow * oh * 3];
        let rows = rgb.chunks_exact_mut(ow * 3);
        self.resolve_rows(frame, colours, rows, |out, row| out.copy_from_slice(row));
        let image =
            image::Rgb32FImage::from_raw(ow as u32, oh as u32, rgb).expect("buffer matches size");
        SrgbImage::from_rgb32f(image)
    }

    /// Each output row's colours, the mean of its subsamples', handed to `emit` with
    /// that row of `rows`.
    fn resolve_rows<'r, T: 'r>(
        &self,
        frame: &render::Frame,
        colours: &SrgbImage,
        rows: impl Iterator<Item = &'r mut [T]>,
        mut emit: impl FnMut(&mut [T], &[f32]),
    ) {
        let k = frame.factor;
        let ow = frame.width / k;
        let data = colours.data();
        let front_samples = self.stats.width * self.stats.height;
        let weight = 1.0 / (k * k) as f32;
        let mut sums = vec![0.0f32; ow * 3];
        let mut overlay = frame.overlay.iter().peekable();
        for (y, out) in rows.enumerate() {
            sums.fill(0.0);
            for sy in 0..k {
                let row = &frame.sample[(y * k + sy) * frame.width..][..ow * k];
                for (px, subsamples) in sums.chunks_exact_mut(3).zip(row.chunks_exact(k)) {
                    for &s in subsamples {
                        let colour = self.sample_colour(s, data, front_samples);
                        for c in 0..3 {
                            px[c] += colour[c] * weight;
                        }
                    }
                }
            }
            let row_end = ((y + 1) * k * frame.width) as u32;
            while let Some(&(i, m)) = overlay.next_if(|(i, _)| *i < row_end) {
                let x = (i as usize % frame.width) / k;
                let behind = self.sample_colour(frame.sample[i as usize], data, front_samples);
                let soft = self.soft_colour(m, behind, data, front_samples);
                for c in 0..3 {
                    sums[3 * x + c] += (soft[c] - behind[c]) * weight;
                }
            }
            // The soft pixels' exchanges can round a mean a hair past [0, 1].
            sums.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            emit(out, &sums);
        }
    }

    /// The colour of soft pixel `m` over `behind`: its background share exchanged for
    /// what lies behind it in this view ([`matte`]).
    fn soft_colour(
        &self,
        m: u32,
        behind: [f32; 3],
        data: &[f32],
        front_samples: usize,
    ) -> [f32; 3] {
        let soft = self.mattes.soft[m as usize];
        let pixel = self.sample_colour(soft.sample, data, front_samples);
        let beneath = self.sample_colour(soft.beneath, data, front_samples);
        let share = 1.0 - soft.alpha;
        std::array::from_fn(|c| (pixel[c] + share * (behind[c] - beneath[c])).clamp(0.0, 1.0))
    }
}

/// Per output pixel, the fractions of its subsamples that show original pixels and
/// that no quad covered.
fn fractions(frame: &render::Frame) -> (Vec<f32>, Vec<f32>) {
    let k = frame.factor;
    let origin = frame
        .origin
        .as_deref()
        .expect("the detailed render rasterises with origins");
    let (ow, oh) = (frame.width / k, frame.height / k);
    let weight = 1.0 / (k * k) as f32;
    let mut front_fraction = vec![0.0; ow * oh];
    let mut hole_fraction = vec![0.0; ow * oh];
    for y in 0..oh {
        for sy in 0..k {
            let row = &origin[(y * k + sy) * frame.width..][..ow * k];
            for (x, subsamples) in row.chunks_exact(k).enumerate() {
                for o in subsamples {
                    match o {
                        Origin::Front => front_fraction[y * ow + x] += weight,
                        Origin::Filled => hole_fraction[y * ow + x] += weight,
                        Origin::Back => {}
                    }
                }
            }
        }
    }
    (front_fraction, hole_fraction)
}

/// Replaces the colours of the pixels no sample covered (in part or whole) by patch
/// synthesis from the rest of the view ([`fill`]).
fn synthesize_holes(rendered: &mut Rendered, frame: &render::Frame) {
    let k = frame.factor;
    let (w, h) = (frame.width / k, frame.height / k);
    let hole: Vec<bool> = rendered.hole_fraction.iter().map(|&f| f > 0.0).collect();
    if !hole.contains(&true) {
        return;
    }
    // The farthest subsample stands for the pixel: a hole opens onto the far side.
    let inv_z: Vec<f32> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (0..k * k)
                .map(|s| frame.inv_z[(y * k + s / k) * frame.width + x * k + s % k])
                .fold(f32::INFINITY, f32::min)
        })
        .collect();
    let mut rgb = rendered.image.data().to_vec();
    fill::synthesize(&mut rgb, &inv_z, &hole, w, h);
    for (i, _) in hole.iter().enumerate().filter(|(_, &o)| o) {
        let (x, y) = ((i % w) as u32, (i / w) as u32);
        rendered
            .image
            .put(x, y, [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]]);
    }
}

impl Ldi {
    /// The colour of a rendered sample; black for [`render::EMPTY`] (a view that sees
    /// none of the mesh, e.g. a camera far behind it or absurdly far to the side).
    fn sample_colour(&self, sample: u32, data: &[f32], front_samples: usize) -> [f32; 3] {
        if sample == render::EMPTY {
            return [0.0; 3];
        }
        let s = sample as usize;
        match &self.band_rgb {
            Some(band) if (front_samples..front_samples + band.len()).contains(&s) => {
                band[s - front_samples]
            }
            _ => {
                let from = 3 * self.mesh.samples[s].colour_from as usize;
                let shade = s
                    .checked_sub(front_samples)
                    .and_then(|k| self.band_shade.get(k));
                shaded([data[from], data[from + 1], data[from + 2]], shade)
            }
        }
    }
}

/// A copied colour with a band sample's smoothing added, kept within [0, 1].
fn shaded(colour: [f32; 3], shade: Option<&[f32; 3]>) -> [f32; 3] {
    match shade {
        Some(o) => std::array::from_fn(|c| (colour[c] + o[c]).clamp(0.0, 1.0)),
        None => colour,
    }
}

/// The power of two nearest the smallest positive depth (1 for a map without one):
/// dividing by a power of two is exact, so a scene already in ordinary units renders
/// bit for bit as without it.
pub(crate) fn mesh_scale(depth: &[f32]) -> f64 {
    let nearest = depth
        .iter()
        .copied()
        .filter(|z| z.is_finite() && *z > 0.0)
        .fold(f32::INFINITY, f32::min);
    if !nearest.is_finite() {
        return 1.0;
    }
    f64::from(nearest)
        .log2()
        .round()
        .clamp(-120.0, 120.0)
        .exp2()
}

/// The most crop framing magnifies a view: past it the view would be mostly outside
/// the photo, and showing the stretched border is the lesser harm.
const MAX_CROP: f64 = 2.0;

/// The magnification that keeps a border `margin` source pixels wide out of the frame.
fn crop_for_margin(margin: f64, source: &Intrinsics) -> f64 {
    let need = |extent: u32| {
        let half = f64::from(extent) / 2.0;
        if margin < half {
            half / (half - margin)
        } else {
            MAX_CROP
        }
    };
    need(source.width).max(need(source.height)).min(MAX_CROP)
}

fn supersampled(k: &Intrinsics, factor: usize) -> Intrinsics {
    let s = factor as f64;
    Intrinsics {
        fx: k.fx * s,
        fy: k.fy * s,
        cx: k.cx * s,
        cy: k.cy * s,
        width: k.width * factor as u32,
        height: k.height * factor as u32,
    }
}

/// The LDI behind the [`Relocator`] interface: built in [`Relocator::prepare`], once
/// per photo, and rendered per view.
pub struct LdiRelocator {
    pub config: LdiConfig,
    /// For a stream of frames of one scene: the largest crop fitted so far, below which
    /// the next preparation does not go, so that the framing does not breathe as the
    /// depth of each frame changes (see [`LdiRelocator::steady`]).
    held_crop: Option<std::sync::Mutex<f64>>,
}

impl LdiRelocator {
    pub fn new(config: LdiConfig) -> Self {
        Self {
            config,
            held_crop: None,
        }
    }

    /// A relocator for the frames of a live stream: crop framing only ever grows from
    /// one preparation to the next. Not for unrelated photos, each of which should get
    /// its own framing.
    pub fn steady(config: LdiConfig) -> Self {
        Self {
            config,
            held_crop: Some(std::sync::Mutex::new(1.0)),
        }
    }
}

impl Default for LdiRelocator {
    fn default() -> Self {
        Self::new(LdiConfig::default())
    }
}

impl Relocator for LdiRelocator {
    fn description(&self) -> String {
        let c = &self.config;
        format!(
            "layered depth image: cut at {} relative disparity steps (contours >= {} px), \
             background band inpainted by patch synthesis from the background side \
             (smoothed over {} px), band colours from the {}, {} silhouettes, {}x{} \
             supersampling, border {}",
            c.edge_threshold,
            c.min_contour_px,
            c.band_smoothing,
            match c.band_colours {
                BandColours::View => "view's image",
                BandColours::Inpainted => "build image",
            },
            c.silhouettes,
            c.supersampling,
            c.supersampling,
            c.border
        )
    }

    fn prepare<'a>(
        &'a self,
        colours: &SrgbImage,
        depth: &DepthMap,
        source: &Intrinsics,
        views: &[ViewCamera],
    ) -> Result<Box<dyn PreparedRelocation + 'a>, RelocateError> {
        let reach = crate::relocate::reach_of(views.iter().map(|v| v.centre), source);
        let mut ldi = Ldi::build(colours, depth, source, &self.config, reach)?;
        ldi.fit_frame(views);
        if let Some(held) = &self.held_crop {
            let mut held = held
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            ldi.stats.crop = ldi.stats.crop.max(*held);
            *held = ldi.stats.crop;
        }
        Ok(Box::new(ldi))
    }
}

impl PreparedRelocation for Ldi {
    fn render(&self, colours: &SrgbImage, view: &ViewCamera) -> Result<SrgbImage, RelocateError> {
        Ldi::render(self, colours, view)
    }

    fn render_rgb8(
        &self,
        colours: &SrgbImage,
        view: &ViewCamera,
    ) -> Result<RgbImage, RelocateError> {
        Ldi::render_rgb8(self, colours, view)
    }

    fn view_map(&self, view: &ViewCamera) -> Option<ViewMap> {
        Ldi::view_map(self, view)
    }
}
