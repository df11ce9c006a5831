//! Checks made before any work, so that a run that cannot succeed says so at once
//! instead of after the depth network, the reshading and the relocation have run:
//! model paths that name the wrong kind of file, and (see [`estimate`]) memory the
//! sizes of a render would need.

use std::path::{Path, PathBuf};

/// A path given where a model manifest belongs.
#[derive(Debug, thiserror::Error)]
pub enum ModelPathError {
    #[error(
        "{flag} {path} is an ONNX graph; {flag} takes the model's manifest, the .json file \
         beside the .onnx: {manifest}{exists}"
    )]
    Onnx {
        flag: &'static str,
        path: PathBuf,
        manifest: PathBuf,
        exists: &'static str,
    },
    #[error(
        "{flag} {path} is not a model manifest (a .json file; it is not text): give the \
         manifest, or the directory that holds the models"
    )]
    NotText { flag: &'static str, path: PathBuf },
}

/// Refuses a reshading `--model` (or `$RESHADER_MODEL`) that names an ONNX file or
/// another binary file instead of a manifest, naming the manifest to give instead.
/// Directories and "none" pass; the loader checks manifests themselves.
pub fn check_model_path(flag: &'static str, path: &Path) -> Result<(), ModelPathError> {
    if path.as_os_str() == "none" || !path.is_file() {
        return Ok(());
    }
    let onnx = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("onnx"));
    if onnx {
        let manifest = path.with_extension("json");
        let exists = if manifest.is_file() {
            ""
        } else {
            " (which does not exist: every model ships with its manifest)"
        };
        return Err(ModelPathError::Onnx {
            flag,
            path: path.into(),
            manifest,
            exists,
        });
    }
    if !starts_as_text(path) {
        return Err(ModelPathError::NotText {
            flag,
            path: path.into(),
        });
    }
    Ok(())
}

/// The reshading model a command will load: `--model`, else `$RESHADER_MODEL`.
pub fn chosen_reshade_model(model: Option<&Path>) -> Option<PathBuf> {
    model
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
}

/// Whether the file's first 4 KiB are UTF-8 (a character cut at the end allowed).
fn starts_as_text(path: &Path) -> bool {
    use std::io::Read;
    let Ok(file) = std::fs::File::open(path) else {
        return true;
    };
    let mut head = Vec::with_capacity(4096);
    if file.take(4096).read_to_end(&mut head).is_err() {
        return true;
    }
    match std::str::from_utf8(&head) {
        Ok(_) => true,
        Err(e) => e.error_len().is_none(),
    }
}

/// Bytes per pixel of the buffers a render keeps, by what they hold (see
/// [`estimate`]); docs/reliability.md lists them with the measurements they were fitted
/// to (peak resident memory and data segment of nine renders; the sum is a high-water
/// mark because the allocator keeps what the networks free for the later stages).
pub mod factors {
    /// Photo: the decoder's buffer, the 8-bit copy, the float image, its depth map and
    /// a resampled copy of it; measured: 12-megapixel photos cost 16 bytes a pixel
    /// more than 2-megapixel ones, the copies being short-lived.
    pub const PHOTO: u64 = 16;
    /// Photo fitted to the views: float image, depth, the network's depth (12 + 4 + 4).
    pub const FITTED: u64 = 20;
    /// Layered depth image per fitted pixel: mesh samples and vertices, disparity, band.
    pub const LDI: u64 = 64;
    /// One view's reshaded colours (float RGB), all views held at once.
    pub const RESHADED: u64 = 12;
    /// One finished view (8-bit RGB), all views held at once.
    pub const VIEW: u64 = 3;
    /// Rendering one view: the 2x2-supersampled id, depth and hole-filling buffers and
    /// the float result, per view pixel.
    pub const VIEW_SCRATCH: u64 = 60;
    /// The quilt and its PNG encoding, per quilt pixel.
    pub const QUILT: u64 = 8;
    /// The panel, its lookup table (nearest's; larger tables add their bytes) and PNG, per
    /// panel pixel.
    pub const PANEL: u64 = 9;
    /// Reshading network activations per working pixel (the photo's pixels at the size
    /// --reshade-scale and --reshade-size leave): the encoder's features and one decoder
    /// run, the latter for each view decoded at once (--reshade-batch times
    /// --parallel-views).
    pub const NET_FEATURES: u64 = 280;
    pub const NET_PER_VIEW: u64 = 350;
    /// The reshading network's weights and engine, whatever the photo.
    pub const NET_FIXED: u64 = 8 << 20;
    /// The depth network (weights, activations at its fixed input size), when depth is
    /// not read from a file: while tract loads and optimises it (before any view
    /// exists), and what it keeps afterwards.
    pub const DEPTH_NET_LOADING: u64 = 136 << 20;
    pub const DEPTH_NET: u64 = 40 << 20;
    /// The process itself: code, allocator arenas, thread stacks, the image codecs.
    pub const BASE: u64 = 48 << 20;
    /// Added to the sum for the allocator's fragmentation and what the factors miss,
    /// in percent.
    pub const SLACK_PERCENT: u64 = 15;
}

/// What a render of a photo for a board involves, for [`estimate`].
#[derive(Clone, Copy, Debug)]
pub struct RenderSize {
    /// The photo's width and height (from its header).
    pub photo: (u32, u32),
    pub views: u32,
    pub view: (u32, u32),
    /// Quilt pixels; 0 when no quilt is written.
    pub quilt_pixels: u64,
    /// Panel pixels; 0 when no panel is written.
    pub panel_pixels: u64,
    /// Bytes of weaving table per subpixel (1 nearest, 3 linear, 4 Gaussian or dimmed).
    pub table_bytes: u64,
    /// The reshading network's working size and views decoded at once; `None` without
    /// a network.
    pub network: Option<NetworkSize>,
    /// Whether the depth network may run.
    pub depth_network: bool,
    /// Reshaded images held at once while the views are relocated (0 without a
    /// network): see [`reshaded_at_once`].
    pub reshaded_at_once: u32,
}

/// An estimate of the memory a render needs, by part.
#[derive(Clone, Debug)]
pub struct MemoryEstimate {
    pub parts: Vec<(&'static str, u64)>,
}

impl MemoryEstimate {
    pub fn total(&self) -> u64 {
        self.parts.iter().map(|p| p.1).fold(0, u64::saturating_add)
    }

    /// The largest parts, for messages: "views 1.2 GiB, panel 96 MiB, …".
    fn largest(&self) -> String {
        let mut parts = self.parts.clone();
        parts.sort_by_key(|p| std::cmp::Reverse(p.1));
        parts
            .iter()
            .take(4)
            .map(|(what, bytes)| format!("{what} {}", crate::io::limits::Bytes(*bytes)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The reshading network's share of a render: the size it runs at (as
/// `NetOptions::working_size` decides) and how many views it decodes at once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NetworkSize {
    pub scale: f64,
    pub max_side: Option<usize>,
    pub at_once: u32,
}

impl NetworkSize {
    /// At the photo's full working size, one view at a time.
    pub const FULL: NetworkSize = NetworkSize {
        scale: 1.0,
        max_side: None,
        at_once: 1,
    };

    pub fn of(reshade: &crate::reshade::net::choice::ReshadeConfig, at_once: u32) -> Self {
        NetworkSize {
            scale: reshade.scale,
            max_side: reshade.max_side,
            at_once,
        }
    }

    /// The pixels the network works on for a fitted photo of `w`x`h`.
    fn working_pixels(&self, (w, h): (u64, u64)) -> u64 {
        let options = crate::reshade::net::NetOptions {
            scale: if self.scale.is_finite() {
                self.scale.clamp(0.0, 1.0)
            } else {
                1.0
            },
            max_side: self.max_side,
            ..Default::default()
        };
        let (ww, wh) = options.working_size(w as usize, h as usize);
        ww as u64 * wh as u64
    }
}

/// The size of the photo once fitted to views of `view`: the pipeline shrinks it to
/// cover the view when it is larger (see `pipeline::Fitted`).
fn fitted_size((pw, ph): (u32, u32), (vw, vh): (u32, u32)) -> (u64, u64) {
    let cover = (f64::from(vw) / f64::from(pw.max(1))).max(f64::from(vh) / f64::from(ph.max(1)));
    if cover < 1.0 {
        let w = (f64::from(pw) * cover).ceil() as u64;
        let h = (f64::from(ph) * cover).ceil() as u64;
        (w.max(1), h.max(1))
    } else {
        (u64::from(pw), u64::from(ph))
    }
}

/// The memory a render of `size` needs at its peak, from the sizes alone, each part a
/// documented factor ([`factors`]) times its pixels. The peak is the larger of two
/// moments. Loading: the reshading network is loaded, the photo decoded, and the depth
/// network loaded, which tract needs far more memory for while it optimises the graph
/// than afterwards. Running: the photo (with a depth map of its size), the fitted photo
/// and the networks are counted throughout, although `render` lets the photo go once it
/// is fitted and estimates depth at the fitted size only: the estimate errs high. Added
/// to them, the larger of relocating the views (the LDI, the reshaded colours of the
/// views in flight, the finished views, the rendering scratch of one view per core) and
/// writing the products (the views and the larger of the quilt and the panel, made one
/// after the other). [`factors::SLACK_PERCENT`] is added. Measured against the peak
/// memory of nine renders (photos of 0.1 to 12 megapixels, four boards, with and without the
/// networks), it lies 1.06x to 1.47x above it, and each passes with --max-memory at its
/// estimate unless the per-input check (a quarter of the ceiling for the photo) refuses
/// it first.
pub fn estimate(size: &RenderSize) -> MemoryEstimate {
    use factors::*;
    let photo = u64::from(size.photo.0) * u64::from(size.photo.1);
    let fitted_wh = fitted_size(size.photo, size.view);
    let fitted = fitted_wh.0 * fitted_wh.1;
    let view = u64::from(size.view.0) * u64::from(size.view.1);
    let n = u64::from(size.views);
    let m = |a: u64, b: u64| a.saturating_mul(b);
    let sum =
        |parts: &[(&'static str, u64)]| parts.iter().map(|p| p.1).fold(0, u64::saturating_add);
    let mut loading = vec![("process", BASE), ("photo", m(photo, PHOTO))];
    if size.network.is_some() {
        loading.push(("reshading network", NET_FIXED));
    }
    if size.depth_network {
        loading.push(("depth network", DEPTH_NET_LOADING));
    }
    let mut parts = vec![
        ("process", BASE),
        ("photo", m(photo, PHOTO)),
        ("fitted photo", m(fitted, FITTED)),
    ];
    if let Some(net) = size.network {
        let working = net.working_pixels(fitted_wh);
        let per_pixel = NET_FEATURES + NET_PER_VIEW * u64::from(net.at_once.max(1));
        parts.push((
            "reshading network",
            NET_FIXED.saturating_add(m(working, per_pixel)),
        ));
    }
    if size.depth_network {
        parts.push(("depth network", DEPTH_NET));
    }
    let views = ("views", m(m(view, VIEW), n));
    let relocating = [
        ("layered depth image", m(fitted, LDI)),
        (
            "reshaded views",
            m(m(fitted, RESHADED), n.min(u64::from(size.reshaded_at_once))),
        ),
        views,
        // Views are relocated one per core at a time.
        (
            "view rendering",
            m(
                m(view, VIEW_SCRATCH),
                n.clamp(1, crate::parallel::cores() as u64),
            ),
        ),
    ];
    let quilt = ("quilt", m(size.quilt_pixels, QUILT));
    let panel = (
        "panel",
        m(size.panel_pixels, PANEL + extra_table(size.table_bytes)),
    );
    let writing = [views, if quilt.1 >= panel.1 { quilt } else { panel }];
    if sum(&relocating) >= sum(&writing) {
        parts.extend(relocating);
    } else {
        parts.extend(writing);
    }
    if sum(&loading) > sum(&parts) {
        parts = loading;
    }
    let slack = sum(&parts) / 100 * SLACK_PERCENT;
    parts.push(("allocator slack", slack));
    MemoryEstimate { parts }
}

/// A run whose estimate exceeds `--max-memory`.
#[derive(Debug, thiserror::Error)]
#[error(
    "{what} would need about {} of memory ({}), more than --max-memory {}; raise \
     --max-memory{hint}",
    crate::io::limits::Bytes(*.needed), .largest, crate::io::limits::Bytes(*.ceiling)
)]
pub struct OverBudget {
    pub what: String,
    pub needed: u64,
    pub ceiling: u64,
    pub largest: String,
    pub hint: &'static str,
}

/// Refuses `estimate` when it is above the run's ceiling.
pub fn check_memory(
    what: impl Into<String>,
    estimate: &MemoryEstimate,
    hint: &'static str,
) -> Result<(), OverBudget> {
    let ceiling = crate::io::limits::max_memory();
    let needed = estimate.total();
    log::info!(
        "memory estimate: {} of --max-memory {} ({})",
        crate::io::limits::Bytes(needed),
        crate::io::limits::Bytes(ceiling),
        estimate.largest()
    );
    if needed > ceiling {
        return Err(OverBudget {
            what: what.into(),
            needed,
            ceiling,
            largest: estimate.largest(),
            hint,
        });
    }
    Ok(())
}

/// Whether reshading will run a network: a chosen `--model`/`$RESHADER_MODEL` other
/// than `none`, or the shipped model directory when none is chosen (as
/// `ReshadeConfig::build` decides).
pub fn reshading_on(model: Option<&Path>) -> bool {
    match chosen_reshade_model(model) {
        Some(path) => path.as_os_str() != "none",
        None => crate::reshade::net::choice::default_model_dir().is_some(),
    }
}

/// The sizes of rendering a photo of `photo` pixels for `board`, writing `products`
/// (empty: all).
pub fn render_size(
    photo: (u32, u32),
    board: &interleave::Board,
    products: &[crate::pipeline::Product],
    reshade: &crate::reshade::net::choice::ReshadeConfig,
    depth_network: bool,
) -> RenderSize {
    use crate::pipeline::Product;
    let wants = |p: Product| products.is_empty() || products.contains(&p);
    let (vw, vh) = board.view_size();
    let (cols, rows) = board.quilt_grid();
    let (pw, ph) = board.panel_size();
    let at_once = views_at_once(reshade);
    RenderSize {
        photo,
        views: board.views() as u32,
        view: (vw, vh),
        quilt_pixels: if wants(Product::Quilt) {
            u64::from(cols * vw) * u64::from(rows * vh)
        } else {
            0
        },
        panel_pixels: if wants(Product::Panel) {
            u64::from(pw) * u64::from(ph)
        } else {
            0
        },
        table_bytes: board.filter().table_bytes_per_subpixel(),
        network: reshading_on(reshade.model.as_deref()).then(|| NetworkSize::of(reshade, at_once)),
        depth_network,
        reshaded_at_once: if reshading_on(reshade.model.as_deref()) {
            reshaded_at_once(reshade, board.views())
        } else {
            0
        },
    }
}

/// The reshaded images a render holds at once, of `views` (the views stream through
/// reshading into relocation): the views the network decodes at once, the residuals of
/// the key views when the others are interpolated, and one view per core being relocated.
pub fn reshaded_at_once(reshade: &crate::reshade::net::choice::ReshadeConfig, views: usize) -> u32 {
    let keys = reshade
        .key_views
        .filter(|&k| (2..views).contains(&k))
        .unwrap_or(0);
    let held = u64::from(views_at_once(reshade))
        .saturating_add(keys as u64)
        .saturating_add(crate::parallel::cores() as u64);
    held.min(views as u64) as u32
}

/// The views the reshading network decodes at once: --reshade-batch times
/// --parallel-views.
pub fn views_at_once(reshade: &crate::reshade::net::choice::ReshadeConfig) -> u32 {
    (reshade.batch.max(1) as u64)
        .saturating_mul(reshade.parallel_views.max(1) as u64)
        .min(u64::from(u32::MAX)) as u32
}

/// What to suggest besides raising the ceiling when a render is over it.
pub const RENDER_HINT: &str =
    " (or write fewer products with --only, or reshade at a smaller --reshade-scale)";

/// The memory `weave` needs: the board's views read in and the panel.
pub fn weave_estimate(board: &interleave::Board) -> MemoryEstimate {
    let (vw, vh) = board.view_size();
    let (pw, ph) = board.panel_size();
    let view = u64::from(vw) * u64::from(vh);
    let panel = u64::from(pw) * u64::from(ph);
    let per = factors::PANEL + extra_table(board.filter().table_bytes_per_subpixel());
    MemoryEstimate {
        parts: vec![
            ("process", factors::BASE),
            (
                "views",
                view.saturating_mul(factors::VIEW + 4)
                    .saturating_mul(board.views() as u64),
            ),
            ("panel", panel.saturating_mul(per)),
        ],
    }
}

/// Panel bytes a weaving table takes beyond nearest's one byte per subpixel.
fn extra_table(bytes_per_subpixel: u64) -> u64 {
    3 * bytes_per_subpixel.saturating_sub(1)
}

/// The sizes of rendering one view at the photo's own resolution (`view`, `reshade`).
pub fn single_view_size(
    photo: (u32, u32),
    reshade: Option<&crate::reshade::net::choice::ReshadeConfig>,
    depth_network: bool,
) -> RenderSize {
    RenderSize {
        photo,
        views: 1,
        view: photo,
        quilt_pixels: 0,
        panel_pixels: 0,
        table_bytes: 1,
        network: reshade
            .and_then(|r| reshading_on(r.model.as_deref()).then(|| NetworkSize::of(r, 1))),
        depth_network,
        reshaded_at_once: 1,
    }
}

/// What to suggest besides raising the ceiling when a single view is over it.
pub const VIEW_HINT: &str = " (or reshade at a smaller --reshade-scale)";

/// The memory loading the depth network needs (with the reshading network loaded
/// first when `reshading`), for commands that load it before any photo.
pub fn depth_network_estimate(reshading: bool) -> MemoryEstimate {
    estimate(&RenderSize {
        photo: (0, 0),
        views: 0,
        view: (0, 0),
        quilt_pixels: 0,
        panel_pixels: 0,
        table_bytes: 1,
        network: reshading.then_some(NetworkSize::FULL),
        depth_network: true,
        reshaded_at_once: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn size(board: &interleave::Board, photo: (u32, u32), networks: bool) -> RenderSize {
        let (vw, vh) = board.view_size();
        let (cols, rows) = board.quilt_grid();
        let (pw, ph) = board.panel_size();
        RenderSize {
            photo,
            views: board.views() as u32,
            view: (vw, vh),
            quilt_pixels: u64::from(cols * vw) * u64::from(rows * vh),
            panel_pixels: u64::from(pw) * u64::from(ph),
            table_bytes: 3,
            network: networks.then_some(NetworkSize::FULL),
            depth_network: networks,
            reshaded_at_once: if networks { 3 } else { 0 },
        }
    }

    /// The estimate must not refuse an ordinary render at the default ceiling: a
    /// 12-megapixel phone photo, either way up, on every built-in board, with both
    /// networks, fits in 4 GiB.
    #[test]
    fn a_phone_photo_fits_the_default_ceiling_on_every_board() {
        for name in interleave::Board::builtin_names() {
            let board = interleave::Board::builtin(name).unwrap();
            for photo in [(4032, 3024), (3024, 4032)] {
                let total = estimate(&size(&board, photo, true)).total();
                assert!(
                    total < crate::io::limits::DEFAULT_MAX_MEMORY,
                    "{name} {photo:?}: {}",
                    crate::io::limits::Bytes(total)
                );
            }
        }
    }

    #[test]
    fn the_estimate_grows_with_every_size_and_names_its_largest_parts() {
        let board = interleave::Board::builtin("looking-glass-portrait").unwrap();
        let small = estimate(&size(&board, (640, 480), false));
        let large = estimate(&size(&board, (4032, 3024), false));
        let networks = estimate(&size(&board, (4032, 3024), true));
        assert!(small.total() < large.total() && large.total() < networks.total());
        let text = networks.largest();
        assert!(text.contains("reshading network"), "{text}");
        // The loading phase wins for a tiny photo with the depth network.
        let tiny = estimate(&RenderSize {
            photo: (24, 16),
            views: 2,
            view: (24, 16),
            quilt_pixels: 0,
            panel_pixels: 0,
            table_bytes: 1,
            network: None,
            depth_network: true,
            reshaded_at_once: 0,
        });
        assert!(tiny.parts.iter().any(|p| p.1 == factors::DEPTH_NET_LOADING));
    }

    /// Views stream from reshading into relocation: a render holds the views decoded at
    /// once, the key views' residuals and one view per core, never more than the board's
    /// views, and the estimate follows that count, not the board's views.
    #[test]
    fn reshaded_views_held_at_once_follow_the_stream_not_the_board() {
        let cores = crate::parallel::cores() as u32;
        let mut config = crate::reshade::net::choice::ReshadeConfig {
            batch: 2,
            parallel_views: 3,
            key_views: None,
            ..Default::default()
        };
        assert_eq!(reshaded_at_once(&config, 66), 6 + cores);
        assert_eq!(reshaded_at_once(&config, 4), 4);
        config.key_views = Some(9);
        assert_eq!(reshaded_at_once(&config, 66), 6 + 9 + cores);
        let board = interleave::Board::builtin("looking-glass-go").unwrap();
        let total = |held: u32| {
            let mut s = size(&board, (4032, 3024), true);
            s.reshaded_at_once = held;
            estimate(&s).total()
        };
        assert!(total(4) < total(66));
        assert_eq!(total(66), total(1000));
    }
}
