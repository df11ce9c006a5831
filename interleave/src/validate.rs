//! The limits a board file or a calibration must keep and the checks that enforce them,
//! with errors that name the file and the field.

use std::path::PathBuf;

use crate::cells::{SubpixelCell, MAX_CELLS, MAX_CELL_OFFSET};
use crate::filter::{ViewFilter, MAX_DIM_EDGES, SIGMA_RANGE};
use crate::lens::{LookingGlass, VanBerkel};

/// Largest view count a board may declare; the weaving tables store view indices as bytes.
pub const MAX_VIEWS: u32 = 256;
/// Largest panel side accepted, in pixels (guards against typos like an extra zero).
pub const MAX_PANEL_SIDE: u32 = 32_768;

/// Lens and panel values outside these ranges are refused, naming the field: within
/// them the lens phase stays exact in f64; beyond them a value is a typo (an exponent
/// gone wrong), not a panel. Real units: pitch 40-90 lenses per inch, slope about ±6
/// to ±8, DPI 280-500, lens pitch 4-20 subpixels.
pub const PITCH_RANGE: (f64, f64) = (1e-3, 1e4);
/// Magnitude of a Looking Glass slope (rows per pixel of lens shift).
pub const SLOPE_RANGE: (f64, f64) = (1e-2, 1e4);
/// Magnitude of a phase offset (Looking Glass `center`, van Berkel `offset`).
pub const MAX_OFFSET: f64 = 1e6;
pub const DPI_RANGE: (f64, f64) = (1.0, 1e5);
/// van Berkel lens pitch, in subpixels.
pub const LENS_PITCH_RANGE: (f64, f64) = (1e-2, 1e6);
/// Magnitude of a van Berkel `tan_slant` (about 89.9 degrees).
pub const MAX_TAN_SLANT: f64 = 1e3;

/// Everything that can go wrong loading a board or a calibration file.
///
/// Every variant names the file (or built-in board) it comes from.
#[derive(Debug, thiserror::Error)]
pub enum BoardError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("{origin}: field `{field}`: {reason}")]
    Invalid {
        origin: String,
        field: String,
        reason: String,
    },
    #[error(
        "unknown board `{name}`; built-in boards are: {}; or give the path of a .toml board file",
        known.join(", ")
    )]
    Unknown { name: String, known: Vec<String> },
}

/// Why `key` is refused: the nearest of `known` when one is close, else all of them.
pub(crate) fn unknown_key(key: &str, known: &[&str], holder: &str) -> String {
    let nearest = known
        .iter()
        .map(|k| (edit_distance(&key.to_lowercase(), &k.to_lowercase()), *k))
        .min()
        .filter(|(d, _)| *d <= key.chars().count().max(3) / 2);
    match nearest {
        Some((_, k)) => format!("unknown key; did you mean `{k}`?"),
        None => format!("unknown key; {holder} holds {}", known.join(", ")),
    }
}

/// Levenshtein distance in characters (keys are short).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let above = row[j + 1];
            row[j + 1] = (above + 1)
                .min(row[j] + 1)
                .min(diagonal + usize::from(ca != cb));
            diagonal = above;
        }
    }
    row[b.len()]
}

/// Builds field errors that name the file the board came from.
pub(crate) struct Validator<'a> {
    pub(crate) origin: &'a str,
}

impl Validator<'_> {
    pub(crate) fn err(&self, field: &str, reason: &str) -> BoardError {
        BoardError::Invalid {
            origin: self.origin.to_string(),
            field: field.to_string(),
            reason: reason.to_string(),
        }
    }

    pub(crate) fn check(&self, ok: bool, field: &str, reason: &str) -> Result<(), BoardError> {
        if ok {
            Ok(())
        } else {
            Err(self.err(field, reason))
        }
    }

    pub(crate) fn check_side(&self, field: &str, value: u32) -> Result<(), BoardError> {
        self.check(
            value > 0 && value <= MAX_PANEL_SIDE,
            field,
            &format!("must be between 1 and {MAX_PANEL_SIDE} pixels, got {value}"),
        )
    }

    pub(crate) fn positive(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && value > 0.0,
            field,
            &format!("must be > 0, got {value}"),
        )
    }

    pub(crate) fn finite(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(value.is_finite(), field, "must be a finite number")
    }

    /// `value` in [lo, hi].
    pub(crate) fn within(
        &self,
        field: &str,
        value: f64,
        (lo, hi): (f64, f64),
    ) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && (lo..=hi).contains(&value),
            field,
            &format!("must be between {lo} and {hi}, got {value}"),
        )
    }

    /// `|value|` in [lo, hi], either sign.
    pub(crate) fn magnitude(
        &self,
        field: &str,
        value: f64,
        (lo, hi): (f64, f64),
    ) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && (lo..=hi).contains(&value.abs()),
            field,
            &format!("must be between {lo} and {hi} in magnitude (either sign), got {value}"),
        )
    }

    pub(crate) fn offset(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && value.abs() <= MAX_OFFSET,
            field,
            &format!("must be between -{MAX_OFFSET} and {MAX_OFFSET}, got {value}"),
        )
    }

    pub(crate) fn looking_glass(&self, lg: &LookingGlass) -> Result<(), BoardError> {
        self.positive("looking_glass.pitch", lg.pitch)?;
        self.within("looking_glass.pitch", lg.pitch, PITCH_RANGE)?;
        self.finite("looking_glass.slope", lg.slope)?;
        self.check(
            lg.slope != 0.0,
            "looking_glass.slope",
            "must not be 0 (that would be horizontal lenses)",
        )?;
        self.magnitude("looking_glass.slope", lg.slope, SLOPE_RANGE)?;
        self.finite("looking_glass.center", lg.center)?;
        self.offset("looking_glass.center", lg.center)?;
        self.positive("looking_glass.dpi", lg.dpi)?;
        self.within("looking_glass.dpi", lg.dpi, DPI_RANGE)?;
        self.cells("looking_glass.subpixel_cells", &lg.subpixel_cells)
    }

    pub(crate) fn filter(&self, f: &ViewFilter) -> Result<(), BoardError> {
        self.within("filter.sigma", f.sigma, SIGMA_RANGE)?;
        self.within("filter.dim_edges", f.dim_edges, (0.0, MAX_DIM_EDGES))
    }

    pub(crate) fn cells(&self, field: &str, cells: &[SubpixelCell]) -> Result<(), BoardError> {
        self.check(
            cells.len() <= MAX_CELLS,
            field,
            &format!("at most {MAX_CELLS} cells, got {}", cells.len()),
        )?;
        for (i, cell) in cells.iter().enumerate() {
            for (c, colour) in ["r", "g", "b"].iter().enumerate() {
                for v in cell.offset(c) {
                    self.check(
                        v.is_finite() && v.abs() <= MAX_CELL_OFFSET,
                        &format!("{field}[{i}].{colour}"),
                        &format!(
                            "offsets are in pixels, between -{MAX_CELL_OFFSET} and \
                             {MAX_CELL_OFFSET}, got {v}"
                        ),
                    )?;
                }
            }
        }
        Ok(())
    }

    pub(crate) fn van_berkel(&self, vb: &VanBerkel) -> Result<(), BoardError> {
        match (vb.slant_deg, vb.tan_slant) {
            (Some(_), Some(_)) => {
                return Err(self.err(
                    "van_berkel.tan_slant",
                    "give either `slant_deg` or `tan_slant`, not both",
                ))
            }
            (None, None) => {
                return Err(self.err(
                    "van_berkel.slant_deg",
                    "missing: give the lens slant as `slant_deg` or `tan_slant`",
                ))
            }
            (Some(deg), None) => self.check(
                deg.is_finite() && deg.abs() < 90.0,
                "van_berkel.slant_deg",
                &format!("must be strictly between -90 and 90 degrees, got {deg}"),
            )?,
            (None, Some(t)) => {
                self.finite("van_berkel.tan_slant", t)?;
                self.check(
                    t.abs() <= MAX_TAN_SLANT,
                    "van_berkel.tan_slant",
                    &format!("must be between -{MAX_TAN_SLANT} and {MAX_TAN_SLANT}, got {t}"),
                )?
            }
        }
        self.positive("van_berkel.lens_pitch", vb.lens_pitch)?;
        self.within("van_berkel.lens_pitch", vb.lens_pitch, LENS_PITCH_RANGE)?;
        self.finite("van_berkel.offset", vb.offset)?;
        self.offset("van_berkel.offset", vb.offset)
    }
}
