//! Weaving N view images into one panel frame through a precomputed lookup table.

use std::str::FromStr;

use image::RgbImage;

use crate::board::Board;
use crate::mapping::{blend_views, nearest_view, Mapping};

/// Errors from weaving and quilt handling.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WeaveError {
    #[error("expected {expected} views, got {got}")]
    ViewCount { expected: usize, got: usize },
    #[error("view {index} is {got_w}x{got_h}, expected {expected_w}x{expected_h}")]
    ViewSize {
        index: usize,
        expected_w: u32,
        expected_h: u32,
        got_w: u32,
        got_h: u32,
    },
    #[error("views must be at least 1x1 pixel, got {width}x{height}")]
    EmptyView { width: u32, height: u32 },
    #[error("a quilt grid needs at least one column and one row, got {cols}x{rows}")]
    EmptyGrid { cols: u32, rows: u32 },
    #[error("{views} views do not fit in a {cols}x{rows} quilt")]
    QuiltTooSmall { views: usize, cols: u32, rows: u32 },
    #[error("a {width}x{height} quilt does not divide into a {cols}x{rows} grid of whole tiles")]
    QuiltNotDivisible {
        width: u32,
        height: u32,
        cols: u32,
        rows: u32,
    },
    #[error("unknown blend mode `{0}`; use `nearest` or `linear`")]
    UnknownBlend(String),
}

/// How a subpixel between two view centres is coloured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Blend {
    /// The one view whose slice of the cone the subpixel falls in.
    #[default]
    Nearest,
    /// A linear mix of the two views whose centres bracket the subpixel's cone position.
    Linear,
}

impl FromStr for Blend {
    type Err = WeaveError;

    fn from_str(s: &str) -> Result<Blend, WeaveError> {
        match s {
            "nearest" => Ok(Blend::Nearest),
            "linear" | "blend" => Ok(Blend::Linear),
            other => Err(WeaveError::UnknownBlend(other.to_string())),
        }
    }
}

/// A board's mapping baked into tables for one view resolution; weaving is then a gather.
#[derive(Debug, Clone)]
pub struct Weaver {
    panel_w: u32,
    panel_h: u32,
    view_w: u32,
    view_h: u32,
    views: usize,
    blend: Blend,
    /// First (or only) view of each panel subpixel, row-major, 3 per pixel.
    view_of: Vec<u8>,
    /// For [`Blend::Linear`]: weight of view `view_of + 1`, in 1/255ths (empty otherwise).
    weight: Vec<u8>,
    /// Byte offset inside a view row of the pixel each panel column samples.
    col_offset: Vec<usize>,
    /// Byte offset inside a view image of the row each panel row samples.
    row_offset: Vec<usize>,
}

impl Weaver {
    /// Precomputes the lookup tables for weaving `view_w`x`view_h` views onto `board`.
    pub fn new(board: &Board, view_w: u32, view_h: u32, blend: Blend) -> Weaver {
        Weaver::from_mapping(&board.mapping(), view_w, view_h, blend)
    }

    /// As [`Weaver::new`], from a mapping directly.
    pub fn from_mapping(mapping: &Mapping, view_w: u32, view_h: u32, blend: Blend) -> Weaver {
        let (panel_w, panel_h) = mapping.panel_size();
        let views = mapping.views();
        let subpixels = panel_w as usize * panel_h as usize * 3;
        let mut view_of = Vec::with_capacity(subpixels);
        let mut weight = Vec::with_capacity(if blend == Blend::Linear { subpixels } else { 0 });
        for y in 0..panel_h {
            for x in 0..panel_w {
                for c in 0..3 {
                    let t = mapping.cone_position(x, y, c);
                    match blend {
                        Blend::Nearest => view_of.push(nearest_view(t, views) as u8),
                        Blend::Linear => {
                            let (v, w) = blend_views(t, views);
                            view_of.push(v as u8);
                            weight.push((w * 255.0).round() as u8);
                        }
                    }
                }
            }
        }
        let (col_offset, row_offset) = if view_w == 0 || view_h == 0 {
            (Vec::new(), Vec::new())
        } else {
            let cols = (0..panel_w)
                .map(|x| mapping.source_x(x, view_w) as usize * 3)
                .collect();
            let rows = (0..panel_h)
                .map(|y| mapping.source_y(y, view_h) as usize * view_w as usize * 3)
                .collect();
            (cols, rows)
        };
        Weaver {
            panel_w,
            panel_h,
            view_w,
            view_h,
            views,
            blend,
            view_of,
            weight,
            col_offset,
            row_offset,
        }
    }

    pub fn panel_size(&self) -> (u32, u32) {
        (self.panel_w, self.panel_h)
    }

    pub fn view_size(&self) -> (u32, u32) {
        (self.view_w, self.view_h)
    }

    pub fn views(&self) -> usize {
        self.views
    }

    pub fn blend(&self) -> Blend {
        self.blend
    }

    /// The (first) view feeding channel `c` of panel pixel (x, y), as baked in the table.
    pub fn view_at(&self, x: u32, y: u32, c: usize) -> usize {
        self.view_of[self.subpixel(x, y, c)] as usize
    }

    fn subpixel(&self, x: u32, y: u32, c: usize) -> usize {
        (y as usize * self.panel_w as usize + x as usize) * 3 + c
    }

    /// Weaves one panel frame from the views (view 0 the leftmost camera).
    pub fn weave(&self, views: &[RgbImage]) -> Result<RgbImage, WeaveError> {
        let mut out = RgbImage::new(self.panel_w, self.panel_h);
        self.weave_into(views, &mut out)?;
        Ok(out)
    }

    /// Weaves into an existing panel-sized frame, so a display loop can reuse its buffer.
    pub fn weave_into(&self, views: &[RgbImage], out: &mut RgbImage) -> Result<(), WeaveError> {
        self.check_views(views)?;
        if out.dimensions() != (self.panel_w, self.panel_h) {
            *out = RgbImage::new(self.panel_w, self.panel_h);
        }
        let sources: Vec<&[u8]> = views.iter().map(|v| v.as_raw().as_slice()).collect();
        let row_len = self.panel_w as usize * 3;
        for (y, out_row) in out.chunks_exact_mut(row_len).enumerate() {
            let table = y * row_len..(y + 1) * row_len;
            let base = self.row_offset[y];
            match self.blend {
                Blend::Nearest => self.gather_row(&sources, base, &self.view_of[table], out_row),
                Blend::Linear => self.blend_row(
                    &sources,
                    base,
                    &self.view_of[table.clone()],
                    &self.weight[table],
                    out_row,
                ),
            }
        }
        Ok(())
    }

    fn gather_row(&self, sources: &[&[u8]], base: usize, view_of: &[u8], out: &mut [u8]) {
        for (x, &col) in self.col_offset.iter().enumerate() {
            let at = base + col;
            for c in 0..3 {
                let s = 3 * x + c;
                out[s] = sources[view_of[s] as usize][at + c];
            }
        }
    }

    fn blend_row(
        &self,
        sources: &[&[u8]],
        base: usize,
        view_of: &[u8],
        weight: &[u8],
        out: &mut [u8],
    ) {
        for (x, &col) in self.col_offset.iter().enumerate() {
            let at = base + col;
            for c in 0..3 {
                let s = 3 * x + c;
                let v = view_of[s] as usize;
                let a = u32::from(sources[v][at + c]);
                let w = u32::from(weight[s]);
                out[s] = if w == 0 {
                    a as u8
                } else {
                    let b = u32::from(sources[v + 1][at + c]);
                    ((a * (255 - w) + b * w + 127) / 255) as u8
                };
            }
        }
    }

    fn check_views(&self, views: &[RgbImage]) -> Result<(), WeaveError> {
        if self.view_w == 0 || self.view_h == 0 {
            return Err(WeaveError::EmptyView {
                width: self.view_w,
                height: self.view_h,
            });
        }
        if views.len() != self.views {
            return Err(WeaveError::ViewCount {
                expected: self.views,
                got: views.len(),
            });
        }
        for (index, v) in views.iter().enumerate() {
            if v.dimensions() != (self.view_w, self.view_h) {
                return Err(WeaveError::ViewSize {
                    index,
                    expected_w: self.view_w,
                    expected_h: self.view_h,
                    got_w: v.width(),
                    got_h: v.height(),
                });
            }
        }
        Ok(())
    }
}
