//! What reshading does to one photo on a board, in one picture: the photo reshaded for
//! the board's outermost views (still in the photo's frame, so that only the shading
//! differs), their difference magnified, and the two views as the panel shows them.

use image::RgbImage;
use interleave::Board;

use super::{reshade_views, BoardRig, PipelineError, Scene};
use crate::io::photo::{SrgbImage, ONE_LEVEL};
use crate::io::record::Timings;
use crate::relocate::Relocator;
use crate::reshade::{Reshader, TrainingFrame};

/// How much the difference between the outermost reshaded images is magnified: a highlight
/// that slides shows as a bright pair of crescents, a faint one still shows.
pub const DIFFERENCE_GAIN: f32 = 4.0;

/// The sheet and the figures it shows.
pub struct Sheet {
    /// Top row: reshaded for the leftmost view | the photo | reshaded for the rightmost
    /// view; bottom row: the leftmost view | the difference of the two reshaded images
    /// ×[`DIFFERENCE_GAIN`] | the rightmost view.
    pub image: RgbImage,
    /// The outermost views' x offsets, in depth-map units.
    pub offsets: [f64; 2],
    /// The x offsets of the cameras they are reshaded for.
    pub shading_offsets: [f64; 2],
    /// Mean absolute difference of the two reshaded images over pixels and channels
    /// (0–1 encoded values).
    pub mean_change: f64,
    /// Share of pixels whose difference exceeds one 8-bit level in some channel.
    pub changed_share: f64,
}

/// The sheet of `scene` for `board`, with the zero-parallax depth, the depthiness and the
/// shading depthiness chosen as `render` chooses them.
pub fn outer_views(
    scene: &Scene,
    board: &Board,
    focus_depthiness: (Option<f64>, Option<f64>),
    shading_depthiness: Option<f64>,
    reshader: &dyn Reshader,
    relocator: &dyn Relocator,
) -> Result<Sheet, PipelineError> {
    let (vw, vh) = board.view_size();
    let fitted = scene.fitted(vw, vh);
    let rigs = BoardRig::new(
        board,
        (&scene.depth, &fitted.reference),
        focus_depthiness,
        shading_depthiness,
    )?;
    let cameras = rigs.rig.cameras(&fitted.reference);
    let shading = rigs.shading.centres();
    let last = cameras.len() - 1;
    let outer = [cameras[0], cameras[last]];
    let outer_shading = [shading[0], shading[last]];
    let frame = TrainingFrame::for_focus(rigs.rig.focus);
    let mut t = Timings::default();
    let (reshaded, relocation) = reshade_views(
        &fitted,
        (&outer, &outer_shading),
        frame,
        reshader,
        relocator,
        &mut t,
    )?;
    let left = relocation.render(&reshaded[0], &outer[0])?;
    let right = relocation.render(&reshaded[1], &outer[1])?;
    let (difference, mean_change, changed_share) = difference(&reshaded[0], &reshaded[1]);
    let tiles = [
        &reshaded[0],
        &fitted.image,
        &reshaded[1],
        &left,
        &difference,
        &right,
    ];
    Ok(Sheet {
        image: grid(&tiles, 3),
        offsets: [outer[0].centre[0], outer[1].centre[0]],
        shading_offsets: [outer_shading[0][0], outer_shading[1][0]],
        mean_change,
        changed_share,
    })
}

/// |a − b| ×[`DIFFERENCE_GAIN`], the mean of |a − b| and the share of pixels changed by
/// more than one 8-bit level.
fn difference(a: &SrgbImage, b: &SrgbImage) -> (SrgbImage, f64, f64) {
    let mut out = SrgbImage::new(a.width(), a.height());
    let (mut sum, mut changed) = (0.0f64, 0usize);
    for y in 0..a.height() {
        for x in 0..a.width() {
            let (p, q) = (a.get(x, y), b.get(x, y));
            let d = [0, 1, 2].map(|c| (p[c] - q[c]).abs());
            sum += d.iter().map(|&v| f64::from(v)).sum::<f64>();
            changed += usize::from(d.iter().any(|&v| v > ONE_LEVEL));
            out.put(x, y, d.map(|v| (v * DIFFERENCE_GAIN).min(1.0)));
        }
    }
    let pixels = (a.width() * a.height()).max(1) as f64;
    (out, sum / (3.0 * pixels), changed as f64 / pixels)
}

/// `tiles` in rows of `columns`, each centred in a cell as large as the largest tile.
fn grid(tiles: &[&SrgbImage], columns: usize) -> RgbImage {
    let cell_w = tiles.iter().map(|t| t.width()).max().unwrap_or(1);
    let cell_h = tiles.iter().map(|t| t.height()).max().unwrap_or(1);
    let rows = tiles.len().div_ceil(columns) as u32;
    let mut sheet = RgbImage::new(cell_w * columns as u32, cell_h * rows);
    for (k, tile) in tiles.iter().enumerate() {
        let (col, row) = ((k % columns) as u32, (k / columns) as u32);
        let x = col * cell_w + (cell_w - tile.width()) / 2;
        let y = row * cell_h + (cell_h - tile.height()) / 2;
        image::imageops::replace(&mut sheet, &tile.to_rgb8(), i64::from(x), i64::from(y));
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn difference_is_magnified_and_counted() {
        let a = SrgbImage::new(2, 1);
        let mut b = SrgbImage::new(2, 1);
        b.put(1, 0, [0.1, 0.0, 0.0]);
        let (d, mean, share) = difference(&a, &b);
        assert_eq!(d.get(0, 0), [0.0; 3]);
        assert!((d.get(1, 0)[0] - 0.4).abs() < 1e-6);
        assert!((mean - 0.1 / 6.0).abs() < 1e-9);
        assert_eq!(share, 0.5);
    }

    #[test]
    fn grid_centres_smaller_tiles_in_equal_cells() {
        let big = SrgbImage::new(4, 2);
        let mut small = SrgbImage::new(2, 2);
        small.put(0, 0, [1.0; 3]);
        let sheet = grid(&[&big, &small, &big], 2);
        assert_eq!(sheet.dimensions(), (8, 4));
        assert_eq!(sheet.get_pixel(5, 0).0, [255; 3]);
        assert_eq!(sheet.get_pixel(4, 0).0, [0; 3]);
    }
}
