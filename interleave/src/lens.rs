//! The panel's optics: how its lens sheet lies over the subpixels, in the terms a board
//! file or a unit's calibration gives them.

use serde::Deserialize;

use crate::cells::{CellPattern, SubpixelCell};

/// Order of the colour subpixels inside one pixel, left to right.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SubpixelLayout {
    #[default]
    Rgb,
    Bgr,
}

impl SubpixelLayout {
    /// Horizontal position (0, 1 or 2) of colour channel `c` (0 = R, 1 = G, 2 = B) in a pixel.
    pub fn position(self, channel: usize) -> usize {
        match self {
            SubpixelLayout::Rgb => channel,
            SubpixelLayout::Bgr => 2 - channel,
        }
    }

    pub(crate) fn flipped(self) -> SubpixelLayout {
        match self {
            SubpixelLayout::Rgb => SubpixelLayout::Bgr,
            SubpixelLayout::Bgr => SubpixelLayout::Rgb,
        }
    }
}

/// Lens sheet in Looking Glass Factory's calibration terms (`visual.json`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LookingGlass {
    /// Lens pitch in lenses per inch, measured perpendicular to the lenses.
    pub pitch: f64,
    /// Lens slope: panel rows per pixel of horizontal lens shift (sign gives the direction).
    pub slope: f64,
    /// Phase offset of the lens sheet, in lenses.
    pub center: f64,
    /// Whether view numbers run against the phase (true on all current Looking Glass units).
    pub inv_view: bool,
    /// Panel dots per inch, used to turn `pitch` into lenses per panel width.
    pub dpi: f64,
    #[serde(default)]
    pub flip_image_x: bool,
    #[serde(default)]
    pub flip_image_y: bool,
    /// Swaps the red and blue subpixel positions relative to the board's `subpixels`.
    #[serde(default)]
    pub flip_subp: bool,
    /// Which of `subpixel_cells` each pixel uses (`CellPatternMode`, 0 to 4).
    #[serde(default)]
    pub cell_pattern: CellPattern,
    /// Each colour subpixel's offset from its pixel centre (`subpixelCells`); empty for
    /// a plain stripe of `subpixels`. When given, `subpixels` and `flip_subp` do not apply.
    #[serde(default)]
    pub subpixel_cells: Vec<SubpixelCell>,
}

/// Lens sheet in van Berkel's terms (slanted lenticular over an RGB stripe panel).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VanBerkel {
    /// Slant of the lens axes from vertical, in degrees (give this or `tan_slant`).
    pub slant_deg: Option<f64>,
    /// Tangent of the slant angle, e.g. 0.3333333333333333 for atan(1/3).
    pub tan_slant: Option<f64>,
    /// Horizontal lens pitch, in subpixels.
    pub lens_pitch: f64,
    /// Offset of subpixel 0 from the lens edge, in subpixels.
    #[serde(default)]
    pub offset: f64,
}

impl VanBerkel {
    /// Tangent of the slant angle, whichever way the file gave it.
    pub fn tan_alpha(&self) -> f64 {
        match (self.tan_slant, self.slant_deg) {
            (Some(t), _) => t,
            (None, Some(deg)) => deg.to_radians().tan(),
            (None, None) => 0.0,
        }
    }
}

/// Plain side-by-side stereo: view 0 on the left half, view 1 on the right half.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SideBySide {}

/// How the panel's optics route subpixels to views.
#[derive(Debug, Clone, PartialEq)]
pub enum Lens {
    LookingGlass(LookingGlass),
    VanBerkel(VanBerkel),
    SideBySide,
}
