//! Weaving N view images into one panel frame through a precomputed lookup table.

use image::RgbImage;

use crate::board::Board;
use crate::filter::{Blend, Taps, ViewFilter};
use crate::mapping::{blend_views, nearest_view, Mapping};

/// Threads used by [`Weaver::new`]: the machine's cores, at most 8 (the gather is
/// memory-bound well before that).
fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().min(8))
}

fn build_table(mapping: &Mapping, filter: ViewFilter, threads: usize) -> Table {
    let (w, h) = mapping.panel_size();
    let row_len = w as usize * 3;
    let len = row_len * h as usize;
    let views = mapping.views();
    if filter.weighted() {
        let mut table = vec![[0u8; 4]; len];
        for_row_chunks(&mut table, row_len, threads, |first, chunk| {
            let taps = filter.tapper(views);
            fill_rows(mapping, first, chunk, |t| weighted_entry(taps(t), views))
        });
        return Table::Weighted {
            taps: views.min(3),
            entries: table,
        };
    }
    match filter.blend {
        Blend::Linear => {
            let mut table = vec![[0u8; 3]; len];
            for_row_chunks(&mut table, row_len, threads, |first, chunk| {
                fill_rows(mapping, first, chunk, |t| {
                    let (v, w) = blend_views(t, views);
                    let second = if w > 0.0 { v + 1 } else { v };
                    // Adding 0.5 and truncating rounds without a libm call.
                    [v as u8, second as u8, (w * 255.0 + 0.5) as u8]
                })
            });
            Table::Linear(table)
        }
        _ => {
            let mut table = vec![0u8; len];
            for_row_chunks(&mut table, row_len, threads, |first, chunk| {
                fill_rows(mapping, first, chunk, |t| nearest_view(t, views) as u8)
            });
            Table::Nearest(table)
        }
    }
}

/// `[first view, weight 0, weight 1, weight 2]`, weights in 1/255ths. The weights are
/// rounded so that they add up to the rounded total, and the first view is moved down
/// where needed so that all three taps are views (a weight past the last view is 0).
fn weighted_entry(taps: Taps, views: usize) -> [u8; 4] {
    let first = taps.first.min(views.saturating_sub(3));
    let shift = taps.first - first;
    let mut w = [0u8; 3];
    for (j, &weight) in taps.weights.iter().enumerate() {
        if let Some(slot) = w.get_mut(j + shift) {
            *slot = (weight * 255.0 + 0.5) as u8;
        }
    }
    let total = (taps.weights.iter().sum::<f64>() * 255.0 + 0.5) as i32;
    let heaviest = (0..3).max_by_key(|&j| w[j]).unwrap_or(0);
    let rest: i32 = w.iter().map(|&x| i32::from(x)).sum::<i32>() - i32::from(w[heaviest]);
    w[heaviest] = (total - rest).clamp(0, 255) as u8;
    [first as u8, w[0], w[1], w[2]]
}

/// Fills table rows `first_row..` with `entry(cone position)` for each subpixel.
fn fill_rows<T>(mapping: &Mapping, first_row: usize, rows: &mut [T], entry: impl Fn(f64) -> T) {
    let row_len = mapping.panel_size().0 as usize * 3;
    let mut t = vec![0.0; row_len];
    for (i, row) in rows.chunks_exact_mut(row_len).enumerate() {
        mapping.cone_positions_row((first_row + i) as u32, &mut t);
        for (slot, &ti) in row.iter_mut().zip(&t) {
            *slot = entry(ti);
        }
    }
}

/// Runs `work(first_row, rows)` over contiguous bands of rows, one band per thread.
fn for_row_chunks<T: Send>(
    data: &mut [T],
    row_len: usize,
    threads: usize,
    work: impl Fn(usize, &mut [T]) + Sync,
) {
    let rows = data.len() / row_len.max(1);
    if threads <= 1 || rows < 2 {
        work(0, data);
        return;
    }
    let band = rows.div_ceil(threads);
    std::thread::scope(|scope| {
        for (i, chunk) in data.chunks_mut(band * row_len).enumerate() {
            let work = &work;
            scope.spawn(move || work(i * band, chunk));
        }
    });
}

/// A black `width`x`height` image whose buffer is reserved fallibly: sizes come from
/// boards and calibration files, and a refused allocation is an error, not an abort.
pub(crate) fn try_image(
    width: u64,
    height: u64,
    what: &'static str,
) -> Result<RgbImage, WeaveError> {
    let too_large = WeaveError::OutOfMemory {
        what,
        width,
        height,
    };
    let (Ok(w), Ok(h)) = (u32::try_from(width), u32::try_from(height)) else {
        return Err(too_large);
    };
    let bytes = width
        .checked_mul(height)
        .and_then(|p| p.checked_mul(3))
        .and_then(|b| usize::try_from(b).ok())
        .ok_or_else(|| too_large.clone())?;
    let mut buffer = Vec::new();
    buffer
        .try_reserve_exact(bytes)
        .map_err(|_| too_large.clone())?;
    buffer.resize(bytes, 0);
    RgbImage::from_raw(w, h, buffer).ok_or(too_large)
}

/// Errors from weaving and quilt handling.
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
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
    #[error("a {width}x{height} {what} cannot be allocated ({} bytes): not enough memory", *width as u128 * *height as u128 * 3)]
    OutOfMemory {
        what: &'static str,
        width: u64,
        height: u64,
    },
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
}

/// Per-subpixel lookup table, row-major, 3 entries per panel pixel.
#[derive(Debug, Clone)]
enum Table {
    /// The view of each subpixel.
    Nearest(Vec<u8>),
    /// Two views and the weight of the second, in 1/255ths. Where no blending happens
    /// both views are the same, so the gather needs no branch.
    Linear(Vec<[u8; 3]>),
    /// Gaussian blending or edge dimming: `taps` consecutive views from the first, with
    /// their weights (see [`weighted_entry`]).
    Weighted { taps: usize, entries: Vec<[u8; 4]> },
}

/// A board's mapping baked into tables for one view resolution; weaving is then a gather.
#[derive(Clone)]
pub struct Weaver {
    panel_w: u32,
    panel_h: u32,
    view_w: u32,
    view_h: u32,
    views: usize,
    threads: usize,
    filter: ViewFilter,
    table: Table,
    /// Byte offset inside a view row of the pixel each panel column samples.
    col_offset: Vec<usize>,
    /// Byte offset inside a view image of the row each panel row samples.
    row_offset: Vec<usize>,
}

/// Summarises instead of dumping millions of table entries into a log.
impl std::fmt::Debug for Weaver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Weaver")
            .field("panel", &(self.panel_w, self.panel_h))
            .field("view", &(self.view_w, self.view_h))
            .field("views", &self.views)
            .field("filter", &self.filter)
            .field("threads", &self.threads)
            .finish_non_exhaustive()
    }
}

impl Weaver {
    /// Precomputes the lookup tables for weaving `view_w`x`view_h` views onto `board`,
    /// with the board's view filter.
    ///
    /// Building and weaving use all available cores; see [`Weaver::with_threads`].
    pub fn new(board: &Board, view_w: u32, view_h: u32) -> Weaver {
        Weaver::from_mapping(
            &board.mapping(),
            view_w,
            view_h,
            board.filter(),
            default_threads(),
        )
    }

    /// As [`Weaver::new`], from a mapping and a filter directly, with an explicit thread
    /// count.
    pub fn from_mapping(
        mapping: &Mapping,
        view_w: u32,
        view_h: u32,
        filter: impl Into<ViewFilter>,
        threads: usize,
    ) -> Weaver {
        let filter = filter.into();
        let (panel_w, panel_h) = mapping.panel_size();
        let threads = threads.max(1);
        let table = build_table(mapping, filter, threads);
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
            views: mapping.views(),
            threads,
            filter,
            table,
            col_offset,
            row_offset,
        }
    }

    /// Sets how many threads [`Weaver::weave`] splits the panel rows over.
    pub fn with_threads(mut self, threads: usize) -> Weaver {
        self.threads = threads.max(1);
        self
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

    pub fn filter(&self) -> ViewFilter {
        self.filter
    }

    /// The view feeding channel `c` of panel pixel (x, y), as baked in the table: the
    /// first of linear's two, the heaviest of a weighted entry's.
    pub fn view_at(&self, x: u32, y: u32, c: usize) -> usize {
        let i = (y as usize * self.panel_w as usize + x as usize) * 3 + c;
        match &self.table {
            Table::Nearest(t) => t[i] as usize,
            Table::Linear(t) => t[i][0] as usize,
            Table::Weighted { entries, .. } => {
                let [first, w @ ..] = entries[i];
                let heaviest = (0..3).rev().max_by_key(|&j| w[j]).unwrap_or(0);
                first as usize + heaviest
            }
        }
    }

    /// Weaves one panel frame from the views (view 0 the leftmost camera).
    pub fn weave(&self, views: &[RgbImage]) -> Result<RgbImage, WeaveError> {
        self.check_views(views)?;
        let mut out = try_image(u64::from(self.panel_w), u64::from(self.panel_h), "panel")?;
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
        for_row_chunks(out, row_len, self.threads, |first_row, chunk| {
            let mut stage = RowStage::new(&sources, self.view_w as usize * 3);
            for (i, out_row) in chunk.chunks_exact_mut(row_len).enumerate() {
                let y = first_row + i;
                let span = y * row_len..(y + 1) * row_len;
                let rows = stage.rows(self.row_offset[y]);
                match &self.table {
                    Table::Nearest(t) => self.gather_row(rows, &t[span], out_row),
                    Table::Linear(t) => self.blend_row(rows, &t[span], out_row),
                    Table::Weighted { taps, entries } => {
                        self.weighted_row(rows, *taps, &entries[span], out_row)
                    }
                }
            }
        });
        Ok(())
    }

    fn gather_row(&self, rows: StagedRows, table: &[u8], out: &mut [u8]) {
        let pixels = out.chunks_exact_mut(3).zip(table.chunks_exact(3));
        for ((px, views), &col) in pixels.zip(&self.col_offset) {
            for c in 0..3 {
                px[c] = rows.at(views[c], col + c);
            }
        }
    }

    fn blend_row(&self, rows: StagedRows, table: &[[u8; 3]], out: &mut [u8]) {
        let pixels = out.chunks_exact_mut(3).zip(table.chunks_exact(3));
        for ((px, entries), &col) in pixels.zip(&self.col_offset) {
            for c in 0..3 {
                let [v0, v1, w] = entries[c];
                let a = u32::from(rows.at(v0, col + c));
                let b = u32::from(rows.at(v1, col + c));
                let w = u32::from(w);
                px[c] = ((a * (255 - w) + b * w + 127) / 255) as u8;
            }
        }
    }

    fn weighted_row(&self, rows: StagedRows, taps: usize, table: &[[u8; 4]], out: &mut [u8]) {
        let pixels = out.chunks_exact_mut(3).zip(table.chunks_exact(3));
        for ((px, entries), &col) in pixels.zip(&self.col_offset) {
            for c in 0..3 {
                let [first, w @ ..] = entries[c];
                let sum: u32 = (0..taps)
                    .zip(w)
                    .map(|(j, w)| u32::from(rows.at(first + j as u8, col + c)) * u32::from(w))
                    .sum();
                px[c] = ((sum + 127) / 255) as u8;
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

/// The one row of every view that the panel rows being woven sample, copied side by side.
///
/// Views are separate allocations whose rows often start at the same offset within a page,
/// so the same row of 48 views falls in the same few L1 cache sets and the gather, which
/// hops between views at every subpixel, misses constantly. Panel rows sampling the same
/// view row are consecutive (several per view row), so copying that row of each view into
/// one contiguous buffer once is cheaper than the misses it saves: the Portrait's weave
/// went from 6.6 to 2.8 ms with two threads.
struct RowStage<'a> {
    sources: &'a [&'a [u8]],
    row_bytes: usize,
    buffer: Vec<u8>,
    staged: Option<usize>,
}

impl<'a> RowStage<'a> {
    fn new(sources: &'a [&'a [u8]], row_bytes: usize) -> RowStage<'a> {
        RowStage {
            sources,
            row_bytes,
            buffer: vec![0; row_bytes * sources.len()],
            staged: None,
        }
    }

    /// The staged rows starting at byte `offset` of each view, copied if not already.
    fn rows(&mut self, offset: usize) -> StagedRows<'_> {
        if self.staged != Some(offset) {
            let row = offset..offset + self.row_bytes;
            for (dst, src) in self
                .buffer
                .chunks_exact_mut(self.row_bytes)
                .zip(self.sources)
            {
                dst.copy_from_slice(&src[row.clone()]);
            }
            self.staged = Some(offset);
        }
        StagedRows {
            buffer: &self.buffer,
            row_bytes: self.row_bytes,
        }
    }
}

#[derive(Clone, Copy)]
struct StagedRows<'a> {
    buffer: &'a [u8],
    row_bytes: usize,
}

impl StagedRows<'_> {
    /// Byte `i` of view `view`'s staged row.
    fn at(self, view: u8, i: usize) -> u8 {
        self.buffer[usize::from(view) * self.row_bytes + i]
    }
}
