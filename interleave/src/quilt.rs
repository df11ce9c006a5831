//! Quilts (all views tiled in one image, Looking-Glass convention) and side-by-side pairs.

use image::{GenericImage, GenericImageView, RgbImage};

use crate::board::Board;
use crate::weave::WeaveError;

/// Tiles views into a `cols`x`rows` quilt: view 0 bottom-left, then left to right, then
/// upward. Tiles without a view stay black.
pub fn make_quilt(views: &[RgbImage], cols: u32, rows: u32) -> Result<RgbImage, WeaveError> {
    check_grid(views.len(), cols, rows)?;
    let (tw, th) = views.first().map(|v| v.dimensions()).unwrap_or((0, 0));
    if tw == 0 || th == 0 {
        return Err(WeaveError::EmptyView {
            width: tw,
            height: th,
        });
    }
    let mut quilt = crate::weave::try_image(
        u64::from(tw) * u64::from(cols),
        u64::from(th) * u64::from(rows),
        "quilt",
    )?;
    for (i, view) in views.iter().enumerate() {
        if view.dimensions() != (tw, th) {
            return Err(WeaveError::ViewSize {
                index: i,
                expected_w: tw,
                expected_h: th,
                got_w: view.width(),
                got_h: view.height(),
            });
        }
        let (x, y) = tile_origin(i, cols, rows, tw, th);
        quilt
            .copy_from(view, x, y)
            .expect("tile lies inside the quilt by construction");
    }
    Ok(quilt)
}

/// Cuts the first `views` tiles back out of a quilt made by [`make_quilt`].
pub fn split_quilt(
    quilt: &RgbImage,
    cols: u32,
    rows: u32,
    views: usize,
) -> Result<Vec<RgbImage>, WeaveError> {
    check_grid(views, cols, rows)?;
    let (w, h) = quilt.dimensions();
    if w == 0 || h == 0 || w % cols != 0 || h % rows != 0 {
        return Err(WeaveError::QuiltNotDivisible {
            width: w,
            height: h,
            cols,
            rows,
        });
    }
    let (tw, th) = (w / cols, h / rows);
    Ok((0..views)
        .map(|i| {
            let (x, y) = tile_origin(i, cols, rows, tw, th);
            quilt.view(x, y, tw, th).to_image()
        })
        .collect())
}

fn check_grid(views: usize, cols: u32, rows: u32) -> Result<(), WeaveError> {
    if cols == 0 || rows == 0 {
        return Err(WeaveError::EmptyGrid { cols, rows });
    }
    if views == 0 || views as u64 > u64::from(cols) * u64::from(rows) {
        return Err(WeaveError::QuiltTooSmall { views, cols, rows });
    }
    Ok(())
}

/// Top-left pixel of tile `i` (image rows count from the top, quilt rows from the bottom).
fn tile_origin(i: usize, cols: u32, rows: u32, tw: u32, th: u32) -> (u32, u32) {
    let col = i as u32 % cols;
    let row_up = i as u32 / cols;
    (col * tw, (rows - 1 - row_up) * th)
}

/// Looking-Glass quilt file name, e.g. `quilt_qs8x6a0.75.png`.
///
/// The aspect is a view's width over its height, written with at most four decimals and
/// no trailing zeros, as Looking Glass tools expect.
pub fn quilt_file_name(cols: u32, rows: u32, aspect: f32) -> String {
    format!("quilt_qs{cols}x{rows}a{}.png", format_aspect(aspect))
}

fn format_aspect(aspect: f32) -> String {
    let fixed = format!("{aspect:.4}");
    let trimmed = fixed.trim_end_matches('0').trim_end_matches('.');
    trimmed.to_string()
}

/// How a quilt is laid out: the views it holds, its grid, and a view's aspect (width over
/// height). Travels in the file's name (`qs{cols}x{rows}a{aspect}`, Looking Glass's
/// convention, where the views fill the grid) and in PNG text metadata
/// ([`QuiltLayout::text`]), which also says how many tiles hold views.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuiltLayout {
    pub views: usize,
    pub cols: u32,
    pub rows: u32,
    pub aspect: f32,
}

impl QuiltLayout {
    /// The layout of `board`'s quilt, for its file's metadata.
    pub fn of(board: &Board) -> Self {
        let (cols, rows) = board.quilt_grid();
        Self {
            views: board.views(),
            cols,
            rows,
            aspect: board.view_aspect(),
        }
    }

    /// The Looking-Glass quilt file name for this grid and view aspect.
    pub fn file_name(&self) -> String {
        quilt_file_name(self.cols, self.rows, self.aspect)
    }
}

/// The PNG text keywords of a quilt's layout.
pub const QUILT_VIEWS_KEY: &str = "Quilt views";
pub const QUILT_COLUMNS_KEY: &str = "Quilt columns";
pub const QUILT_ROWS_KEY: &str = "Quilt rows";
pub const QUILT_ASPECT_KEY: &str = "Quilt aspect";

/// Why a quilt's layout cannot be known or does not fit its image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QuiltLayoutError {
    #[error(
        "no quilt layout: the file has no `{QUILT_COLUMNS_KEY}` and `{QUILT_ROWS_KEY}` \
         metadata and its name no `qs{{cols}}x{{rows}}a{{aspect}}` (e.g. \
         photo_qs8x6a0.75.png)"
    )]
    Missing,
    #[error("metadata `{key}`: {reason}")]
    Field { key: &'static str, reason: String },
    #[error("the metadata says {metadata} but the name says {name}; fix or remove one")]
    Disagree { metadata: String, name: String },
    #[error("a {width}x{height} image does not divide into {cols}x{rows} tiles")]
    NotDivisible {
        width: u32,
        height: u32,
        cols: u32,
        rows: u32,
    },
}

impl QuiltLayout {
    /// The layout's PNG text chunks (keyword, value).
    pub fn text(&self) -> Vec<(&'static str, String)> {
        vec![
            (QUILT_VIEWS_KEY, self.views.to_string()),
            (QUILT_COLUMNS_KEY, self.cols.to_string()),
            (QUILT_ROWS_KEY, self.rows.to_string()),
            (QUILT_ASPECT_KEY, format_aspect(self.aspect)),
        ]
    }

    /// The layout a file name carries (`…qs8x6a0.75…`); the grid is full of views.
    pub fn from_file_name(name: &str) -> Option<QuiltLayout> {
        name.match_indices("qs").find_map(|(at, _)| {
            let rest = &name[at + 2..];
            let (cols, rest) = leading(rest, |c| c.is_ascii_digit())?;
            let rest = rest.strip_prefix('x')?;
            let (rows, rest) = leading(rest, |c| c.is_ascii_digit())?;
            let rest = rest.strip_prefix('a')?;
            let (aspect, _) = leading(rest, |c| c.is_ascii_digit() || c == '.')?;
            let (cols, rows): (u32, u32) = (cols.parse().ok()?, rows.parse().ok()?);
            let aspect: f32 = aspect.trim_end_matches('.').parse().ok()?;
            let views = usize::try_from(u64::from(cols) * u64::from(rows)).ok()?;
            (cols > 0 && rows > 0 && aspect.is_finite() && aspect > 0.0).then_some(QuiltLayout {
                views,
                cols,
                rows,
                aspect,
            })
        })
    }

    /// The layout in the text chunks of a `width`x`height` PNG, `None` when it has none
    /// of the quilt keys. Columns and rows are required together; views default to the
    /// whole grid and the aspect to the tiles' own.
    pub fn from_text(
        text: &[(String, String)],
        (width, height): (u32, u32),
    ) -> Result<Option<QuiltLayout>, QuiltLayoutError> {
        let get = |key: &'static str| {
            text.iter()
                .find(|(k, _)| k == key)
                .map(|(_, v)| (key, v.trim()))
        };
        let keys = [
            QUILT_VIEWS_KEY,
            QUILT_COLUMNS_KEY,
            QUILT_ROWS_KEY,
            QUILT_ASPECT_KEY,
        ];
        if keys.iter().all(|k| get(k).is_none()) {
            return Ok(None);
        }
        let count = |key: &'static str| -> Result<Option<u32>, QuiltLayoutError> {
            get(key)
                .map(|(key, v)| {
                    v.parse::<u32>().ok().filter(|n| *n > 0).ok_or_else(|| {
                        QuiltLayoutError::Field {
                            key,
                            reason: format!("expected a whole number of at least 1, got `{v}`"),
                        }
                    })
                })
                .transpose()
        };
        let required = |key: &'static str| {
            count(key)?.ok_or(QuiltLayoutError::Field {
                key,
                reason: "missing (the other quilt keys are present)".into(),
            })
        };
        let (cols, rows) = (required(QUILT_COLUMNS_KEY)?, required(QUILT_ROWS_KEY)?);
        let tiles = u64::from(cols) * u64::from(rows);
        let views = match count(QUILT_VIEWS_KEY)? {
            Some(v) if u64::from(v) > tiles => {
                return Err(QuiltLayoutError::Field {
                    key: QUILT_VIEWS_KEY,
                    reason: format!("{v} views do not fit a {cols}x{rows} grid"),
                })
            }
            Some(v) => v as usize,
            None => tiles as usize,
        };
        let aspect = match get(QUILT_ASPECT_KEY) {
            None => (width / cols) as f32 / (height / rows).max(1) as f32,
            Some((key, v)) => v
                .parse::<f32>()
                .ok()
                .filter(|a| a.is_finite() && *a > 0.0)
                .ok_or_else(|| QuiltLayoutError::Field {
                    key,
                    reason: format!("expected a positive number, got `{v}`"),
                })?,
        };
        Ok(Some(QuiltLayout {
            views,
            cols,
            rows,
            aspect,
        }))
    }

    /// The layout of a `width`x`height` quilt named `name` with text chunks `text`: the
    /// metadata's, else the name's. When both are there they must agree on the grid.
    pub fn resolve(
        name: &str,
        text: &[(String, String)],
        (width, height): (u32, u32),
    ) -> Result<QuiltLayout, QuiltLayoutError> {
        let from_name = QuiltLayout::from_file_name(name);
        let layout = match (QuiltLayout::from_text(text, (width, height))?, from_name) {
            (Some(meta), Some(name)) if (meta.cols, meta.rows) != (name.cols, name.rows) => {
                return Err(QuiltLayoutError::Disagree {
                    metadata: format!("{}x{}", meta.cols, meta.rows),
                    name: format!("{}x{}", name.cols, name.rows),
                })
            }
            (Some(meta), _) => meta,
            (None, Some(name)) => name,
            (None, None) => return Err(QuiltLayoutError::Missing),
        };
        if width == 0 || height == 0 || width % layout.cols != 0 || height % layout.rows != 0 {
            return Err(QuiltLayoutError::NotDivisible {
                width,
                height,
                cols: layout.cols,
                rows: layout.rows,
            });
        }
        Ok(layout)
    }
}

/// The longest prefix of `s` whose characters pass `keep` (non-empty), and the rest.
fn leading(s: &str, keep: impl Fn(char) -> bool) -> Option<(&str, &str)> {
    let end = s.find(|c| !keep(c)).unwrap_or(s.len());
    (end > 0).then(|| s.split_at(end))
}

/// A stereo pair side by side: `left` then `right`, top-aligned; a shorter image leaves
/// black below it.
pub fn side_by_side(left: &RgbImage, right: &RgbImage) -> RgbImage {
    let height = left.height().max(right.height());
    let mut out = RgbImage::new(left.width() + right.width(), height);
    out.copy_from(left, 0, 0)
        .expect("left image fits by construction");
    out.copy_from(right, left.width(), 0)
        .expect("right image fits by construction");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solid(w: u32, h: u32, value: u8) -> RgbImage {
        RgbImage::from_pixel(w, h, image::Rgb([value, value / 2, 255 - value]))
    }

    #[test]
    fn view_zero_is_bottom_left_and_views_run_right_then_up() {
        let views: Vec<RgbImage> = (0..6).map(|i| solid(2, 3, i as u8 * 10)).collect();
        let q = make_quilt(&views, 3, 2).unwrap();
        assert_eq!(q.dimensions(), (6, 6));
        // Bottom row of tiles (image rows 3..6): views 0, 1, 2 from the left.
        assert_eq!(q.get_pixel(0, 5)[0], 0);
        assert_eq!(q.get_pixel(2, 4)[0], 10);
        assert_eq!(q.get_pixel(5, 3)[0], 20);
        // Top row of tiles: views 3, 4, 5.
        assert_eq!(q.get_pixel(0, 0)[0], 30);
        assert_eq!(q.get_pixel(3, 1)[0], 40);
        assert_eq!(q.get_pixel(4, 2)[0], 50);
    }

    #[test]
    fn file_name_follows_looking_glass() {
        assert_eq!(quilt_file_name(8, 6, 0.75), "quilt_qs8x6a0.75.png");
        assert_eq!(quilt_file_name(11, 6, 0.5625), "quilt_qs11x6a0.5625.png");
        assert_eq!(quilt_file_name(5, 9, 16.0 / 9.0), "quilt_qs5x9a1.7778.png");
        assert_eq!(quilt_file_name(2, 1, 1.0), "quilt_qs2x1a1.png");
    }

    #[test]
    fn layout_from_names() {
        let l = QuiltLayout::from_file_name("quilt_qs8x6a0.75.png").unwrap();
        assert_eq!((l.views, l.cols, l.rows, l.aspect), (48, 8, 6, 0.75));
        let l = QuiltLayout::from_file_name("hologram_qs5x9a1.77778").unwrap();
        assert_eq!((l.cols, l.rows, l.aspect), (5, 9, 1.77778));
        // Other "qs" in the name are passed over.
        let l = QuiltLayout::from_file_name("qsmall_qs2x1a1.png").unwrap();
        assert_eq!((l.cols, l.rows, l.aspect), (2, 1, 1.0));
        for bad in [
            "quilt.png",
            "qs8x6.png",
            "qs0x6a1.png",
            "qs8x6a.png",
            "qsAx6a1",
        ] {
            assert_eq!(QuiltLayout::from_file_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn layout_from_metadata_and_its_errors() {
        let text = |pairs: &[(&str, &str)]| -> Vec<(String, String)> {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        };
        let full = QuiltLayout {
            views: 45,
            cols: 8,
            rows: 6,
            aspect: 0.75,
        };
        let pairs: Vec<(String, String)> = full
            .text()
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        assert_eq!(QuiltLayout::from_text(&pairs, (80, 60)), Ok(Some(full)));
        assert_eq!(
            QuiltLayout::from_text(&text(&[("Software", "x")]), (80, 60)),
            Ok(None)
        );
        let err = QuiltLayout::from_text(&text(&[(QUILT_COLUMNS_KEY, "8")]), (80, 60)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "metadata `Quilt rows`: missing (the other quilt keys are present)"
        );
        let err = QuiltLayout::from_text(
            &text(&[(QUILT_COLUMNS_KEY, "8"), (QUILT_ROWS_KEY, "six")]),
            (80, 60),
        )
        .unwrap_err();
        assert!(err.to_string().contains("got `six`"), "{err}");
        let err = QuiltLayout::from_text(
            &text(&[
                (QUILT_COLUMNS_KEY, "2"),
                (QUILT_ROWS_KEY, "2"),
                (QUILT_VIEWS_KEY, "5"),
            ]),
            (80, 60),
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("5 views do not fit a 2x2 grid"),
            "{err}"
        );
        // Name and metadata disagreeing, neither present, tiles that do not divide.
        let meta = text(&[(QUILT_COLUMNS_KEY, "4"), (QUILT_ROWS_KEY, "2")]);
        let err = QuiltLayout::resolve("x_qs8x6a0.75.png", &meta, (80, 60)).unwrap_err();
        assert!(matches!(err, QuiltLayoutError::Disagree { .. }), "{err}");
        let err = QuiltLayout::resolve("x.png", &[], (80, 60)).unwrap_err();
        assert_eq!(err, QuiltLayoutError::Missing);
        let err = QuiltLayout::resolve("x.png", &meta, (81, 60)).unwrap_err();
        assert!(
            err.to_string()
                .contains("81x60 image does not divide into 4x2"),
            "{err}"
        );
        // Metadata without the name, and the aspect from the tiles when not given.
        let l = QuiltLayout::resolve("x.png", &meta, (80, 60)).unwrap();
        assert_eq!((l.views, l.cols, l.rows, l.aspect), (8, 4, 2, 20.0 / 30.0));
    }

    #[test]
    fn quilt_errors_are_specific() {
        let views = vec![solid(2, 2, 1), solid(2, 3, 2)];
        assert_eq!(
            make_quilt(&views, 2, 1),
            Err(WeaveError::ViewSize {
                index: 1,
                expected_w: 2,
                expected_h: 2,
                got_w: 2,
                got_h: 3
            })
        );
        assert_eq!(
            make_quilt(&views, 1, 1),
            Err(WeaveError::QuiltTooSmall {
                views: 2,
                cols: 1,
                rows: 1
            })
        );
        let q = solid(7, 4, 0);
        assert!(matches!(
            split_quilt(&q, 2, 2, 4),
            Err(WeaveError::QuiltNotDivisible { .. })
        ));
    }

    #[test]
    fn side_by_side_places_left_then_right() {
        let sbs = side_by_side(&solid(3, 2, 10), &solid(2, 4, 200));
        assert_eq!(sbs.dimensions(), (5, 4));
        assert_eq!(sbs.get_pixel(2, 1)[0], 10);
        assert_eq!(sbs.get_pixel(3, 3)[0], 200);
        assert_eq!(
            sbs.get_pixel(0, 3)[0],
            0,
            "below the shorter image stays black"
        );
    }
}
