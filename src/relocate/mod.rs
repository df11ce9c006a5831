//! Relocation: rendering the photo's colours from another camera.
//!
//! A [`Relocator`] first prepares a photo once (its depth and camera, and colours that
//! guide any inpainting), then renders each view from that preparation with the view's
//! own (reshaded) colours. Two implementations sit behind it: the layered depth image
//! ([`crate::relocate::ldi::LdiRelocator`], the default) and [`MeshWarp`], the first forward-warp
//! renderer, kept for comparison: the depth map becomes a triangle mesh with a vertex per
//! pixel centre; triangles that the view would stretch across a depth edge are cut, the
//! rest are rasterised with a z-buffer, and the holes left behind (disocclusions) take
//! the colour of the farthest rendered pixel around them, so foreground is never smeared
//! over what it uncovers.

pub mod ldi;
pub mod map;

use crate::depth::DepthMap;
use crate::io::photo::SrgbImage;
use crate::relocate::ldi::{
    view_reach, Border, LdiConfig, LdiRelocator, Silhouettes, BAND_SMOOTHING_PX,
};
use crate::relocate::map::ViewMap;
use crate::views::{Intrinsics, ViewCamera};
use image::RgbImage;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RelocateError {
    #[error(
        "colours ({colour_w}x{colour_h}), depth ({depth_w}x{depth_h}) and camera \
         ({camera_w}x{camera_h}) sizes differ"
    )]
    SizeMismatch {
        colour_w: u32,
        colour_h: u32,
        depth_w: usize,
        depth_h: usize,
        camera_w: u32,
        camera_h: u32,
    },
    #[error(
        "a relocation map made for a {}x{} image was given a {what} of {}x{}",
        expected.0, expected.1, got.0, got.1
    )]
    MapSize {
        what: &'static str,
        expected: (u32, u32),
        got: (u32, u32),
    },
}

/// Renders the views of a photo whose colours and depth were taken by the `source`
/// camera.
pub trait Relocator: Send + Sync {
    /// What run.json records under "relocate".
    fn description(&self) -> String;

    /// The per-photo work, done once: `colours` guide inpainting (each view brings its
    /// own colours to [`PreparedRelocation::render`]), `views` are the cameras to serve
    /// (the background behind occluders reaches as far as the farthest of them sees,
    /// [`reach_of`], and crop framing fits them); other views still render, with less
    /// background behind occluders.
    fn prepare<'a>(
        &'a self,
        colours: &SrgbImage,
        depth: &DepthMap,
        source: &Intrinsics,
        views: &[ViewCamera],
    ) -> Result<Box<dyn PreparedRelocation + 'a>, RelocateError>;

    /// One view on its own: prepares for just this view and renders it.
    fn render(
        &self,
        colours: &SrgbImage,
        depth: &DepthMap,
        source: &Intrinsics,
        view: &ViewCamera,
    ) -> Result<SrgbImage, RelocateError> {
        self.prepare(colours, depth, source, std::slice::from_ref(view))?
            .render(colours, view)
    }
}

/// A photo prepared by a [`Relocator`]; views render from it on several threads at once.
pub trait PreparedRelocation: Sync {
    /// The view seen by `view`, with `colours` (the view's reshaded image, in the
    /// source camera's frame, at the prepared size).
    fn render(&self, colours: &SrgbImage, view: &ViewCamera) -> Result<SrgbImage, RelocateError>;

    /// [`PreparedRelocation::render`] rounded to 8 bits, as the panel shows it.
    fn render_rgb8(
        &self,
        colours: &SrgbImage,
        view: &ViewCamera,
    ) -> Result<RgbImage, RelocateError> {
        Ok(self.render(colours, view)?.to_rgb8())
    }

    /// The view as a lookup into the colours ([`ViewMap`]), where the preparation can
    /// give one: where every view pixel's colours come from depends on the geometry
    /// alone. None where rendering also synthesises colours per view.
    fn view_map(&self, _view: &ViewCamera) -> Option<ViewMap> {
        None
    }
}

/// The reach a preparation needs to serve cameras at `centres`: the largest equivalent
/// sideways offset among them (see [`view_reach`]).
pub fn reach_of(centres: impl IntoIterator<Item = [f64; 3]>, source: &Intrinsics) -> f64 {
    centres
        .into_iter()
        .map(|c| view_reach(c, source))
        .fold(0.0, f64::max)
}

/// Which relocator the runtime uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RelocateKind {
    /// Layered depth image: cut at depth edges, background inpainted behind occluders.
    #[default]
    Ldi,
    /// The first forward-warp renderer (depth mesh, background-side hole filling).
    Mesh,
}

impl crate::io::keyword::Keyword for RelocateKind {
    const ALL: &'static [(Self, &'static str)] = &[(Self::Ldi, "ldi"), (Self::Mesh, "mesh")];
}

/// What the relocation options of `render`, `view`, `convert`, `watch` ask for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelocateConfig {
    pub kind: RelocateKind,
    /// Beyond the photo's borders (LDI).
    pub border: Border,
    /// How the pixels that mix the two sides of a depth step are drawn (LDI).
    pub silhouettes: Silhouettes,
    /// Radius of the box that smooths the inpainted background band (LDI, px; 0: off).
    pub band_smoothing: usize,
}

impl Default for RelocateConfig {
    fn default() -> Self {
        Self {
            kind: RelocateKind::default(),
            border: Border::default(),
            silhouettes: Silhouettes::default(),
            band_smoothing: BAND_SMOOTHING_PX,
        }
    }
}

impl RelocateConfig {
    /// The one constructor of the runtime's relocator (CLI, gallery, benchmark).
    pub fn build(&self) -> Box<dyn Relocator> {
        match self.kind {
            RelocateKind::Ldi => Box::new(LdiRelocator::new(self.ldi_config())),
            RelocateKind::Mesh => Box::new(MeshWarp::default()),
        }
    }

    /// The relocator of a live stream, whose framing holds steady across its frames
    /// ([`LdiRelocator::steady`]).
    pub fn build_live(&self) -> Box<dyn Relocator> {
        // Live views are lookups into each frame, made once per key frame; a soft
        // pixel is a blend of three pixels and a smoothed band sample a copy plus an
        // offset, which a lookup cannot express.
        let config = LdiConfig {
            silhouettes: Silhouettes::Hard,
            band_smoothing: 0,
            ..self.ldi_config()
        };
        match self.kind {
            RelocateKind::Ldi => Box::new(LdiRelocator::steady(config)),
            RelocateKind::Mesh => Box::new(MeshWarp::default()),
        }
    }

    fn ldi_config(&self) -> LdiConfig {
        LdiConfig {
            border: self.border,
            silhouettes: self.silhouettes,
            band_smoothing: self.band_smoothing,
            ..LdiConfig::default()
        }
    }
}

/// Depth-mesh rasterisation with background-side hole filling.
#[derive(Clone, Copy, Debug)]
pub struct MeshWarp {
    /// A triangle is cut when its corners' parallax differs by more than this many
    /// view pixels, i.e. when the view would stretch it across a depth edge. Monocular
    /// depth spreads edges over a few pixels; at 1 px such ramps tear inside objects.
    pub cut_px: f64,
}

impl Default for MeshWarp {
    fn default() -> Self {
        Self { cut_px: 2.0 }
    }
}

/// A reflected fill pixel counts as background when it is at most this much (relative)
/// nearer than the background pixel at the hole's edge.
const BACKGROUND_TOLERANCE: f32 = 0.1;

/// A mesh vertex in view pixels, with its view-space depth.
#[derive(Clone, Copy)]
struct Vertex {
    u: f64,
    v: f64,
    inv_z: f64,
    valid: bool,
}

/// The rendered view before hole filling: depth 0 marks an uncovered pixel.
struct Frame {
    width: usize,
    height: usize,
    colour: Vec<[f32; 3]>,
    depth: Vec<f32>,
}

impl Relocator for MeshWarp {
    fn description(&self) -> String {
        format!(
            "depth-mesh rasterisation, cut at {} px parallax step, background-side hole fill",
            self.cut_px
        )
    }

    /// The mesh is re-projected per view, so preparing only keeps the depth, in the
    /// warp's own units as the LDI does (divided by the power of two nearest its nearest
    /// depth, cameras likewise): at depth 1e-30 the parallax and inverse depths
    /// underflowed in view pixels and every view came out black.
    fn prepare<'a>(
        &'a self,
        colours: &SrgbImage,
        depth: &DepthMap,
        source: &Intrinsics,
        _views: &[ViewCamera],
    ) -> Result<Box<dyn PreparedRelocation + 'a>, RelocateError> {
        check_sizes(colours, depth, source)?;
        let unit = crate::relocate::ldi::mesh_scale(depth.data());
        let scaled = depth.data().iter().map(|&z| (f64::from(z) / unit) as f32);
        Ok(Box::new(PreparedMesh {
            warp: *self,
            depth: DepthMap::new(depth.width(), depth.height(), scaled.collect()),
            source: *source,
            unit,
        }))
    }
}

struct PreparedMesh {
    warp: MeshWarp,
    /// Depth divided by `unit`.
    depth: DepthMap,
    source: Intrinsics,
    unit: f64,
}

impl PreparedRelocation for PreparedMesh {
    fn render(&self, colours: &SrgbImage, view: &ViewCamera) -> Result<SrgbImage, RelocateError> {
        let (depth, source) = (&self.depth, &self.source);
        check_sizes(colours, depth, source)?;
        let view = &ViewCamera {
            centre: view.centre.map(|c| c / self.unit),
            intrinsics: view.intrinsics,
        };
        let vertices = project_vertices(depth, source, view);
        let mut frame = Frame::new(
            view.intrinsics.width as usize,
            view.intrinsics.height as usize,
        );
        let scale = view.intrinsics.fx / source.fx;
        let (w, h) = (depth.width(), depth.height());
        for y in 0..h.saturating_sub(1) {
            for x in 0..w.saturating_sub(1) {
                let (a, b, c, d) = (
                    y * w + x,
                    y * w + x + 1,
                    (y + 1) * w + x,
                    (y + 1) * w + x + 1,
                );
                for tri in [[a, b, c], [b, d, c]] {
                    let corners = tri.map(|i| vertices[i]);
                    if corners.iter().all(|v| v.valid)
                        && stretch(&corners, tri, w, scale) <= self.warp.cut_px
                    {
                        let tri_colours = tri.map(|i| pixel(colours, i, w));
                        frame.rasterise(corners, tri_colours);
                    }
                }
            }
        }
        let horizontal = view.centre[0].abs() >= view.centre[1].abs();
        Ok(frame.fill_holes_from_background(horizontal))
    }
}

/// Calls `visit(pixel index, barycentric weights)` for every pixel centre of a
/// `width`×`height` grid inside the triangle with screen corners `p`. Edges count as
/// inside, with a little slack, so pixels on an edge two triangles share or on a mesh
/// border are never lost; f64 keeps that true for 12-megapixel frames, where f32
/// rounding of the edge functions exceeds the slack. Shared by both relocators.
pub(crate) fn raster_triangle(
    p: [[f64; 2]; 3],
    width: usize,
    height: usize,
    mut visit: impl FnMut(usize, [f64; 3]),
) {
    let area =
        (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
    if area.abs() < 1e-12 {
        return;
    }
    let inv_area = 1.0 / area;
    let min_u = p[0][0].min(p[1][0]).min(p[2][0]);
    let max_u = p[0][0].max(p[1][0]).max(p[2][0]);
    let min_v = p[0][1].min(p[1][1]).min(p[2][1]);
    let max_v = p[0][1].max(p[1][1]).max(p[2][1]);
    // The bounds get the same slack as the edge test: a vertex that should sit on a
    // pixel centre may land a rounding error beyond it.
    const EPS: f64 = 1e-7;
    let x0 = first_centre(min_u - 0.5 - EPS, width);
    let y0 = first_centre(min_v - 0.5 - EPS, height);
    let x1 = past_last_centre(max_u - 0.5 + EPS, width);
    let y1 = past_last_centre(max_v - 0.5 + EPS, height);
    for y in y0..y1 {
        let pv = y as f64 + 0.5;
        for x in x0..x1 {
            let pu = x as f64 + 0.5;
            let w0 = ((p[1][0] - pu) * (p[2][1] - pv) - (p[2][0] - pu) * (p[1][1] - pv)) * inv_area;
            let w1 = ((p[2][0] - pu) * (p[0][1] - pv) - (p[0][0] - pu) * (p[2][1] - pv)) * inv_area;
            let w2 = 1.0 - w0 - w1;
            if w0 >= -EPS && w1 >= -EPS && w2 >= -EPS {
                visit(y * width + x, [w0, w1, w2]);
            }
        }
    }
}

/// `ceil(t)` clamped to `0..=len`, NaN as 0. Casts instead of `f64::ceil`, which is a
/// libm call on baseline x86-64 and was a tenth of the rasteriser's time; through i64,
/// which x86-64 converts in one instruction (usize takes a branchy sequence).
pub(crate) fn first_centre(t: f64, len: usize) -> usize {
    if t.is_nan() || t <= 0.0 {
        return 0;
    }
    let t = t.min(len as f64);
    let i = t as i64;
    (i + i64::from((i as f64) < t)) as usize
}

/// `floor(t) + 1` clamped to `0..=len`, NaN as 0.
pub(crate) fn past_last_centre(t: f64, len: usize) -> usize {
    if t.is_nan() || t < 0.0 {
        return 0;
    }
    ((t.min(len as f64) as i64 + 1) as usize).min(len)
}

/// How much the view pulls a triangle's corners apart, in view pixels: the spread of
/// their parallax (view position minus source position at the view's scale). Exact for
/// sideways cameras; for cameras moving along z it ignores the small zoom of the sheared
/// projection, which does not cut through objects.
fn stretch(corners: &[Vertex; 3], tri: [usize; 3], width: usize, scale: f64) -> f64 {
    let parallax = |k: usize| {
        let (x, y) = ((tri[k] % width) as f64, (tri[k] / width) as f64);
        (corners[k].u - x * scale, corners[k].v - y * scale)
    };
    let p = [parallax(0), parallax(1), parallax(2)];
    let dist = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).hypot(a.1 - b.1);
    dist(p[0], p[1]).max(dist(p[1], p[2])).max(dist(p[0], p[2]))
}

/// Colours, depth and camera of one photo must have one size.
pub(crate) fn check_sizes(
    colours: &SrgbImage,
    depth: &DepthMap,
    source: &Intrinsics,
) -> Result<(), RelocateError> {
    let c = (colours.width() as usize, colours.height() as usize);
    let d = (depth.width(), depth.height());
    let k = (source.width as usize, source.height as usize);
    if c != d || c != k {
        return Err(RelocateError::SizeMismatch {
            colour_w: colours.width(),
            colour_h: colours.height(),
            depth_w: depth.width(),
            depth_h: depth.height(),
            camera_w: source.width,
            camera_h: source.height,
        });
    }
    Ok(())
}

fn pixel(image: &SrgbImage, index: usize, width: usize) -> [f32; 3] {
    image.get((index % width) as u32, (index / width) as u32)
}

fn project_vertices(depth: &DepthMap, source: &Intrinsics, view: &ViewCamera) -> Vec<Vertex> {
    let w = depth.width();
    depth
        .data()
        .iter()
        .enumerate()
        .map(|(i, &z)| {
            let (u, v) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            let p = source.unproject(u, v, f64::from(z));
            match view.project(p) {
                Some(([u, v], z)) => Vertex {
                    u,
                    v,
                    inv_z: 1.0 / z,
                    valid: true,
                },
                None => Vertex {
                    u: 0.0,
                    v: 0.0,
                    inv_z: 0.0,
                    valid: false,
                },
            }
        })
        .collect()
}

impl Frame {
    fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            colour: vec![[0.0; 3]; width * height],
            depth: vec![0.0; width * height],
        }
    }

    /// Fills the pixel centres inside the triangle where it is nearer than what is
    /// there. 1/z is affine in screen space, so it is interpolated linearly.
    fn rasterise(&mut self, p: [Vertex; 3], colours: [[f32; 3]; 3]) {
        let (depth, colour) = (&mut self.depth, &mut self.colour);
        raster_triangle(p.map(|v| [v.u, v.v]), self.width, self.height, |i, b| {
            let inv_z = b[0] * p[0].inv_z + b[1] * p[1].inv_z + b[2] * p[2].inv_z;
            let z = (1.0 / inv_z) as f32;
            if depth[i] == 0.0 || z < depth[i] {
                depth[i] = z;
                colour[i] = std::array::from_fn(|c| {
                    (b[0] as f32) * colours[0][c]
                        + (b[1] as f32) * colours[1][c]
                        + (b[2] as f32) * colours[2][c]
                });
            }
        });
    }

    /// Each uncovered pixel is filled from the farther of the nearest covered pixels on
    /// either side of it along the baseline (`horizontal` or vertical): disocclusions
    /// open between a foreground edge and the background along that line. Only holes
    /// with nothing on that line look across it. See [`Frame::mirrored`] for which
    /// background pixel gives the colour.
    fn fill_holes_from_background(self, horizontal: bool) -> SrgbImage {
        let (w, h) = (self.width, self.height);
        let along_rows = self.nearest_covered(true);
        let along_cols = self.nearest_covered(false);
        let mut out = SrgbImage::new(w as u32, h as u32);
        for i in 0..w * h {
            let source = if self.depth[i] > 0.0 {
                Some(i)
            } else {
                let by_rows = || {
                    self.farthest(along_rows[i])
                        .map(|s| self.mirrored(i, s, true))
                };
                let by_cols = || {
                    self.farthest(along_cols[i])
                        .map(|s| self.mirrored(i, s, false))
                };
                if horizontal {
                    by_rows().or_else(by_cols)
                } else {
                    by_cols().or_else(by_rows)
                }
            };
            if let Some(s) = source {
                out.put((i % w) as u32, (i / w) as u32, self.colour[s]);
            }
        }
        out
    }

    fn farthest(&self, pair: [Option<usize>; 2]) -> Option<usize> {
        pair.into_iter()
            .flatten()
            .max_by(|&a, &b| self.depth[a].total_cmp(&self.depth[b]))
    }

    /// The pixel that fills hole `i` from background pixel `edge` on the same row (or
    /// column): the reflection of `i` about `edge`, so the background's texture continues
    /// into the hole instead of one pixel being smeared across it; `edge` itself when the
    /// reflection is outside the frame, uncovered, or nearer than the background.
    fn mirrored(&self, i: usize, edge: usize, rows: bool) -> usize {
        let w = self.width;
        let (pos, edge_pos, len) = if rows {
            (i % w, edge % w, w)
        } else {
            (i / w, edge / w, self.height)
        };
        let Some(m) = (2 * edge_pos).checked_sub(pos).filter(|&m| m < len) else {
            return edge;
        };
        let mirror = if rows {
            edge - edge_pos + m
        } else {
            m * w + edge % w
        };
        let background = self.depth[edge];
        if self.depth[mirror] >= background * (1.0 - BACKGROUND_TOLERANCE) {
            mirror
        } else {
            edge
        }
    }

    /// For every pixel, the nearest covered pixel before and after it along its row
    /// (`rows`) or column.
    fn nearest_covered(&self, rows: bool) -> Vec<[Option<usize>; 2]> {
        let (w, h) = (self.width, self.height);
        let (lines, len) = if rows { (h, w) } else { (w, h) };
        let index = |line: usize, k: usize| if rows { line * w + k } else { k * w + line };
        let mut out = vec![[None, None]; w * h];
        for line in 0..lines {
            let mut last = None;
            for k in 0..len {
                let i = index(line, k);
                if self.depth[i] > 0.0 {
                    last = Some(i);
                }
                out[i][0] = last;
            }
            last = None;
            for k in (0..len).rev() {
                let i = index(line, k);
                if self.depth[i] > 0.0 {
                    last = Some(i);
                }
                out[i][1] = last;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests;
