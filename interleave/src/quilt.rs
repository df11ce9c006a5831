//! Quilts (all views tiled in one image, Looking-Glass convention) and side-by-side pairs.

use image::{GenericImage, GenericImageView, RgbImage};

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
