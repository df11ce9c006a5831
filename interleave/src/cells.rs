//! Subpixel cells: where each colour subpixel really sits, for panels whose subpixels are
//! not a plain R-G-B stripe.
//!
//! Looking Glass's current panels (the 16" and 32" Spatial Displays) describe their
//! subpixels in `visual.json` as a list of *cells* (`subpixelCells`), each giving the
//! red, green and blue subpixel's offset from the pixel centre in pixels (X to the
//! right, Y upward), and a *pattern* (`CellPatternMode`) saying which cell each pixel
//! uses. With `x` the pixel column and `y_up` its row counted from the bottom:
//!
//! ```text
//! mode 0: cell 0 everywhere
//! mode 1: checkerboard, cell (x + y_up) mod 2
//! mode 2: cell y_up mod 4
//! mode 3: cell (y_up + 2·(x mod 2)) mod 4
//! mode 4: cell x mod 2
//! ```
//!
//! and the result is taken modulo the number of cells. Each subpixel's lens phase is then
//! the Looking Glass formula evaluated at the subpixel's own position instead of at
//! `u + c/(3W)` (see [`crate::LensPhase::looking_glass`]).

use serde::Deserialize;

/// Most cells a calibration may list (Looking Glass's readers stop at 16 as well).
pub const MAX_CELLS: usize = 16;
/// Largest subpixel offset accepted, in pixels: a subpixel lies inside its pixel, so
/// anything beyond this is a typo.
pub const MAX_CELL_OFFSET: f64 = 2.0;

/// One cell: the (X, Y) offset of each colour subpixel from the pixel centre, in pixels,
/// X to the right and Y upward.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubpixelCell {
    pub r: [f64; 2],
    pub g: [f64; 2],
    pub b: [f64; 2],
}

impl SubpixelCell {
    /// Offset of colour channel `c` (0 R, 1 G, 2 B).
    pub fn offset(&self, c: usize) -> [f64; 2] {
        [self.r, self.g, self.b][c]
    }
}

/// Which cell each pixel uses (`CellPatternMode` 0 to 4; see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(try_from = "u8")]
pub enum CellPattern {
    #[default]
    Uniform,
    Checkerboard,
    FourRows,
    FourRowsStaggered,
    AlternateColumns,
}

impl TryFrom<u8> for CellPattern {
    type Error = String;

    fn try_from(mode: u8) -> Result<CellPattern, String> {
        match mode {
            0 => Ok(CellPattern::Uniform),
            1 => Ok(CellPattern::Checkerboard),
            2 => Ok(CellPattern::FourRows),
            3 => Ok(CellPattern::FourRowsStaggered),
            4 => Ok(CellPattern::AlternateColumns),
            other => Err(format!("cell pattern must be 0, 1, 2, 3 or 4, got {other}")),
        }
    }
}

impl CellPattern {
    /// The cell of pixel column `x`, row `y_up` counted from the bottom, among `count`.
    pub fn cell(self, x: u32, y_up: u32, count: usize) -> usize {
        let (x, y) = (x as usize, y_up as usize);
        let cell = match self {
            CellPattern::Uniform => 0,
            CellPattern::Checkerboard => (x + y) % 2,
            CellPattern::FourRows => y % 4,
            CellPattern::FourRowsStaggered => (y + 2 * (x % 2)) % 4,
            CellPattern::AlternateColumns => x % 2,
        };
        cell % count.max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_pick_cells_as_published() {
        let cells = |p: CellPattern, n: usize| -> Vec<usize> {
            (0..4)
                .flat_map(|y| (0..2).map(move |x| p.cell(x, y, n)))
                .collect()
        };
        // Pixels listed (x, y_up) = (0,0), (1,0), (0,1), (1,1), (0,2), (1,2), (0,3), (1,3).
        assert_eq!(cells(CellPattern::Uniform, 4), [0; 8]);
        assert_eq!(
            cells(CellPattern::Checkerboard, 4),
            [0, 1, 1, 0, 0, 1, 1, 0]
        );
        assert_eq!(cells(CellPattern::FourRows, 4), [0, 0, 1, 1, 2, 2, 3, 3]);
        assert_eq!(cells(CellPattern::FourRows, 2), [0, 0, 1, 1, 0, 0, 1, 1]);
        assert_eq!(
            cells(CellPattern::FourRowsStaggered, 4),
            [0, 2, 1, 3, 2, 0, 3, 1]
        );
        assert_eq!(
            cells(CellPattern::AlternateColumns, 2),
            [0, 1, 0, 1, 0, 1, 0, 1]
        );
        assert!(CellPattern::try_from(5).is_err());
    }
}
