//! Panel descriptions ("boards"): TOML files, built-in boards and per-unit calibration.
//!
//! A board names the panel's native resolution, how many views it shows, how those views
//! are packed into a quilt, and how its lens sheet maps subpixels to views. The lens sheet
//! is given in one of three forms (Looking-Glass calibration values, van Berkel's slanted
//! lenticular parameters, or plain side-by-side stereo); [`Board::mapping`] reduces all of
//! them to one [`Mapping`].

use std::fmt;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::cells::{CellPattern, SubpixelCell, MAX_CELLS, MAX_CELL_OFFSET};
use crate::filter::{ViewFilter, MAX_DIM_EDGES, SIGMA_RANGE};
use crate::lens::{Lens, LookingGlass, SideBySide, SubpixelLayout, VanBerkel};
use crate::mapping::{LensPhase, Mapping};

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

/// The keys a Looking Glass `visual.json` may hold: those read here and those the
/// weave has no use for (configVersion, serial, fringe, verticalAngle). Any other key is refused with the
/// nearest of these, so that a misspelt `invVeiw` cannot pass silently.
pub const VISUAL_JSON_KEYS: &[&str] = &[
    "configVersion",
    "serial",
    "pitch",
    "slope",
    "center",
    "fringe",
    "viewCone",
    "invView",
    "verticalAngle",
    "DPI",
    "screenW",
    "screenH",
    "flipImageX",
    "flipImageY",
    "flipSubp",
    "CellPatternMode",
    "subpixelCells",
];

/// Built-in boards, embedded at compile time from the workspace's `boards/` directory.
const BUILTIN: &[(&str, &str)] = &[
    (
        "looking-glass-portrait",
        include_str!("../../boards/looking-glass-portrait.toml"),
    ),
    (
        "looking-glass-go",
        include_str!("../../boards/looking-glass-go.toml"),
    ),
    (
        "looking-glass-16-gen2",
        include_str!("../../boards/looking-glass-16-gen2.toml"),
    ),
    (
        "looking-glass-16-spatial",
        include_str!("../../boards/looking-glass-16-spatial.toml"),
    ),
    (
        "looking-glass-16-spatial-portrait",
        include_str!("../../boards/looking-glass-16-spatial-portrait.toml"),
    ),
    (
        "looking-glass-32-spatial",
        include_str!("../../boards/looking-glass-32-spatial.toml"),
    ),
    (
        "looking-glass-32-spatial-portrait",
        include_str!("../../boards/looking-glass-32-spatial-portrait.toml"),
    ),
    (
        "generic-8view",
        include_str!("../../boards/generic-8view.toml"),
    ),
    (
        "generic-4view",
        include_str!("../../boards/generic-4view.toml"),
    ),
    ("sbs-2view", include_str!("../../boards/sbs-2view.toml")),
];

const BUILTIN_NAMES: &[&str] = &[
    "looking-glass-portrait",
    "looking-glass-go",
    "looking-glass-16-gen2",
    "looking-glass-16-spatial",
    "looking-glass-16-spatial-portrait",
    "looking-glass-32-spatial",
    "looking-glass-32-spatial-portrait",
    "generic-8view",
    "generic-4view",
    "sbs-2view",
];

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

/// The on-disk form of a board; [`Board`] is its validated counterpart.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardFile {
    name: String,
    #[serde(default)]
    description: String,
    width: u32,
    height: u32,
    views: u32,
    quilt_cols: u32,
    quilt_rows: u32,
    view_width: Option<u32>,
    view_height: Option<u32>,
    view_cone_deg: f64,
    #[serde(default)]
    subpixels: SubpixelLayout,
    looking_glass: Option<LookingGlass>,
    van_berkel: Option<VanBerkel>,
    side_by_side: Option<SideBySide>,
    #[serde(default)]
    filter: ViewFilter,
}

/// A validated panel description.
#[derive(Debug, Clone, PartialEq)]
pub struct Board {
    name: String,
    description: String,
    origin: String,
    width: u32,
    height: u32,
    views: u32,
    quilt_cols: u32,
    quilt_rows: u32,
    view_size: (u32, u32),
    view_cone_deg: f64,
    subpixels: SubpixelLayout,
    lens: Lens,
    filter: ViewFilter,
}

impl Board {
    /// Loads a built-in board by name (see [`Board::builtin_names`]).
    pub fn builtin(name: &str) -> Result<Board, BoardError> {
        let (_, text) = BUILTIN
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| unknown_board(name))?;
        Board::from_toml_str(text, &format!("built-in board `{name}`"))
    }

    /// Names of the boards embedded in the library.
    pub fn builtin_names() -> &'static [&'static str] {
        BUILTIN_NAMES
    }

    /// Loads and validates a board file.
    pub fn from_path(path: &Path) -> Result<Board, BoardError> {
        let text = std::fs::read_to_string(path).map_err(|source| BoardError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Board::from_toml_str(&text, &path.display().to_string())
    }

    /// A built-in board name, or else the path of a board file.
    ///
    /// Anything that looks like a path (has a separator or ends in `.toml`) or names an
    /// existing file is read from disk; everything else must be a built-in name.
    pub fn resolve(name_or_path: &str) -> Result<Board, BoardError> {
        if BUILTIN_NAMES.contains(&name_or_path) {
            return Board::builtin(name_or_path);
        }
        let path = Path::new(name_or_path);
        let looks_like_path = name_or_path.contains(std::path::MAIN_SEPARATOR)
            || name_or_path.contains('/')
            || name_or_path.ends_with(".toml");
        if looks_like_path || path.is_file() {
            Board::from_path(path)
        } else {
            Err(unknown_board(name_or_path))
        }
    }

    /// Parses and validates board TOML; `origin` names the source in error messages.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Board, BoardError> {
        let file: BoardFile = toml::from_str(text).map_err(|e| BoardError::Parse {
            origin: origin.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        Board::validate(file, origin)
    }

    fn validate(f: BoardFile, origin: &str) -> Result<Board, BoardError> {
        let v = Validator { origin };
        v.check(!f.name.trim().is_empty(), "name", "must not be empty")?;
        v.check_side("width", f.width)?;
        v.check_side("height", f.height)?;
        v.check(
            (2..=MAX_VIEWS).contains(&f.views),
            "views",
            &format!("must be between 2 and {MAX_VIEWS}, got {}", f.views),
        )?;
        v.check(f.quilt_cols > 0, "quilt_cols", "must be > 0")?;
        v.check(f.quilt_rows > 0, "quilt_rows", "must be > 0")?;
        v.check(
            u64::from(f.quilt_cols) * u64::from(f.quilt_rows) >= u64::from(f.views),
            "quilt_rows",
            &format!(
                "a {}x{} quilt has room for {} views, but the board has {}",
                f.quilt_cols,
                f.quilt_rows,
                f.quilt_cols * f.quilt_rows,
                f.views
            ),
        )?;
        v.check(
            f.view_cone_deg.is_finite() && f.view_cone_deg > 0.0 && f.view_cone_deg < 180.0,
            "view_cone_deg",
            &format!("must be in (0, 180) degrees, got {}", f.view_cone_deg),
        )?;
        let view_size = v.view_size(&f)?;
        let lens = v.lens(&f)?;
        v.filter(&f.filter)?;
        Ok(Board {
            name: f.name,
            description: f.description,
            origin: origin.to_string(),
            width: f.width,
            height: f.height,
            views: f.views,
            quilt_cols: f.quilt_cols,
            quilt_rows: f.quilt_rows,
            view_size,
            view_cone_deg: f.view_cone_deg,
            subpixels: f.subpixels,
            lens,
            filter: f.filter,
        })
    }

    /// Reads a Looking-Glass `visual.json` and applies it (see [`Board::apply_calibration`]).
    pub fn apply_calibration_file(&mut self, path: &Path) -> Result<(), BoardError> {
        let cal = Calibration::from_path(path)?;
        self.apply_calibration(&cal)
    }

    /// Overrides this board's lens values with a unit's calibration.
    ///
    /// Only Looking-Glass-form boards can take one. `screenW`/`screenH` replace the panel
    /// size and `viewCone` the view cone when present.
    pub fn apply_calibration(&mut self, cal: &Calibration) -> Result<(), BoardError> {
        let Lens::LookingGlass(lg) = &mut self.lens else {
            return Err(BoardError::Invalid {
                origin: cal.origin.clone(),
                field: "pitch".into(),
                reason: format!(
                    "a Looking-Glass calibration cannot apply to board `{}`, whose lens is not \
                     described in Looking-Glass form",
                    self.name
                ),
            });
        };
        lg.pitch = cal.pitch;
        lg.slope = cal.slope;
        lg.center = cal.center;
        set_if(&mut lg.inv_view, cal.inv_view);
        set_if(&mut lg.dpi, cal.dpi);
        set_if(&mut lg.flip_image_x, cal.flip_image_x);
        set_if(&mut lg.flip_image_y, cal.flip_image_y);
        set_if(&mut lg.flip_subp, cal.flip_subp);
        set_if(&mut lg.cell_pattern, cal.cell_pattern);
        if let Some(cells) = &cal.subpixel_cells {
            lg.subpixel_cells.clone_from(cells);
        }
        set_if(&mut self.width, cal.screen_w);
        set_if(&mut self.height, cal.screen_h);
        set_if(&mut self.view_cone_deg, cal.view_cone_deg);
        log::info!(
            "board {}: calibration {} applied (pitch {}, slope {}, center {}; panel {}x{})",
            self.name,
            cal.origin,
            cal.pitch,
            cal.slope,
            cal.center,
            self.width,
            self.height
        );
        self.origin = format!("{} calibrated by {}", self.origin, cal.origin);
        Ok(())
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn description(&self) -> &str {
        &self.description
    }

    /// Where the board came from (file path or built-in name), for messages and run logs.
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// Native panel size in pixels.
    pub fn panel_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn views(&self) -> usize {
        self.views as usize
    }

    /// Quilt grid as (columns, rows).
    pub fn quilt_grid(&self) -> (u32, u32) {
        (self.quilt_cols, self.quilt_rows)
    }

    pub fn view_cone_deg(&self) -> f32 {
        self.view_cone_deg as f32
    }

    /// Size of one quilt tile, the resolution views are rendered at by default.
    pub fn view_size(&self) -> (u32, u32) {
        self.view_size
    }

    /// View aspect (width / height) as it appears in quilt file names.
    pub fn view_aspect(&self) -> f32 {
        self.view_size.0 as f32 / self.view_size.1 as f32
    }

    pub fn subpixels(&self) -> SubpixelLayout {
        self.subpixels
    }

    pub fn lens(&self) -> &Lens {
        &self.lens
    }

    /// How views are blended and dimmed when weaving (the board file's `[filter]`).
    pub fn filter(&self) -> ViewFilter {
        self.filter
    }

    /// Replaces the view filter (a command-line override), checked as a board file's.
    pub fn set_filter(&mut self, filter: ViewFilter) -> Result<(), BoardError> {
        Validator {
            origin: "the view filter",
        }
        .filter(&filter)?;
        self.filter = filter;
        Ok(())
    }

    /// The subpixel → view mapping all lens descriptions reduce to.
    pub fn mapping(&self) -> Mapping {
        let (w, h) = (self.width, self.height);
        match &self.lens {
            Lens::LookingGlass(lg) if !lg.subpixel_cells.is_empty() => Mapping::cells(
                w,
                h,
                self.views,
                LensPhase::looking_glass(lg, w, h),
                lg.cell_pattern,
                &lg.subpixel_cells,
                (lg.flip_image_x, lg.flip_image_y),
            ),
            Lens::LookingGlass(lg) => {
                let layout = if lg.flip_subp {
                    self.subpixels.flipped()
                } else {
                    self.subpixels
                };
                Mapping::lenticular(
                    w,
                    h,
                    self.views,
                    layout,
                    LensPhase::looking_glass(lg, w, h),
                    (lg.flip_image_x, lg.flip_image_y),
                )
            }
            Lens::VanBerkel(vb) => Mapping::lenticular(
                w,
                h,
                self.views,
                self.subpixels,
                LensPhase::van_berkel(vb),
                (false, false),
            ),
            Lens::SideBySide => Mapping::side_by_side(w, h),
        }
    }
}

/// The keys of one `subpixelCells` entry: each colour's offset in pixels.
const CELL_KEYS: &[&str] = &[
    "ROffsetX", "ROffsetY", "GOffsetX", "GOffsetY", "BOffsetX", "BOffsetY",
];

/// Why `key` is refused: the nearest of `known` when one is close, else all of them.
fn unknown_key(key: &str, known: &[&str], holder: &str) -> String {
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

fn set_if<T: Copy>(slot: &mut T, value: Option<T>) {
    if let Some(v) = value {
        *slot = v;
    }
}

fn unknown_board(name: &str) -> BoardError {
    BoardError::Unknown {
        name: name.to_string(),
        known: BUILTIN_NAMES.iter().map(|s| s.to_string()).collect(),
    }
}

/// Builds field errors that name the file the board came from.
struct Validator<'a> {
    origin: &'a str,
}

impl Validator<'_> {
    fn err(&self, field: &str, reason: &str) -> BoardError {
        BoardError::Invalid {
            origin: self.origin.to_string(),
            field: field.to_string(),
            reason: reason.to_string(),
        }
    }

    fn check(&self, ok: bool, field: &str, reason: &str) -> Result<(), BoardError> {
        if ok {
            Ok(())
        } else {
            Err(self.err(field, reason))
        }
    }

    fn check_side(&self, field: &str, value: u32) -> Result<(), BoardError> {
        self.check(
            value > 0 && value <= MAX_PANEL_SIDE,
            field,
            &format!("must be between 1 and {MAX_PANEL_SIDE} pixels, got {value}"),
        )
    }

    fn positive(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && value > 0.0,
            field,
            &format!("must be > 0, got {value}"),
        )
    }

    fn finite(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(value.is_finite(), field, "must be a finite number")
    }

    /// `value` in [lo, hi].
    fn within(&self, field: &str, value: f64, (lo, hi): (f64, f64)) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && (lo..=hi).contains(&value),
            field,
            &format!("must be between {lo} and {hi}, got {value}"),
        )
    }

    /// `|value|` in [lo, hi], either sign.
    fn magnitude(&self, field: &str, value: f64, (lo, hi): (f64, f64)) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && (lo..=hi).contains(&value.abs()),
            field,
            &format!("must be between {lo} and {hi} in magnitude (either sign), got {value}"),
        )
    }

    fn offset(&self, field: &str, value: f64) -> Result<(), BoardError> {
        self.check(
            value.is_finite() && value.abs() <= MAX_OFFSET,
            field,
            &format!("must be between -{MAX_OFFSET} and {MAX_OFFSET}, got {value}"),
        )
    }

    fn view_size(&self, f: &BoardFile) -> Result<(u32, u32), BoardError> {
        match (f.view_width, f.view_height) {
            (Some(w), Some(h)) => {
                self.check_side("view_width", w)?;
                self.check_side("view_height", h)?;
                Ok((w, h))
            }
            (None, None) => Ok(default_view_size(f)),
            (Some(_), None) => Err(self.err("view_height", "must be given with `view_width`")),
            (None, Some(_)) => Err(self.err("view_width", "must be given with `view_height`")),
        }
    }

    fn lens(&self, f: &BoardFile) -> Result<Lens, BoardError> {
        match (&f.looking_glass, &f.van_berkel, &f.side_by_side) {
            (Some(lg), None, None) => {
                self.looking_glass(lg)?;
                Ok(Lens::LookingGlass(lg.clone()))
            }
            (None, Some(vb), None) => {
                self.van_berkel(vb)?;
                Ok(Lens::VanBerkel(vb.clone()))
            }
            (None, None, Some(_)) => {
                self.check(
                    f.views == 2,
                    "views",
                    &format!(
                        "a side-by-side board shows exactly 2 views, got {}",
                        f.views
                    ),
                )?;
                Ok(Lens::SideBySide)
            }
            (None, None, None) => Err(self.err(
                "looking_glass",
                "no lens description: add one of the tables [looking_glass], [van_berkel] \
                 or [side_by_side]",
            )),
            _ => Err(self.err(
                "looking_glass",
                "more than one lens description: keep exactly one of [looking_glass], \
                 [van_berkel] and [side_by_side]",
            )),
        }
    }

    fn looking_glass(&self, lg: &LookingGlass) -> Result<(), BoardError> {
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

    fn filter(&self, f: &ViewFilter) -> Result<(), BoardError> {
        self.within("filter.sigma", f.sigma, SIGMA_RANGE)?;
        self.within("filter.dim_edges", f.dim_edges, (0.0, MAX_DIM_EDGES))
    }

    fn cells(&self, field: &str, cells: &[SubpixelCell]) -> Result<(), BoardError> {
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

    fn van_berkel(&self, vb: &VanBerkel) -> Result<(), BoardError> {
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

/// Quilt tile size when a board does not give one: the panel's aspect, with the whole
/// quilt fitting in 4096x4096 (the texture size Looking Glass tools work with).
fn default_view_size(f: &BoardFile) -> (u32, u32) {
    const QUILT_SIDE: f64 = 4096.0;
    let aspect = f64::from(f.width) / f64::from(f.height);
    let max_w = QUILT_SIDE / f64::from(f.quilt_cols);
    let max_h = QUILT_SIDE / f64::from(f.quilt_rows);
    let (w, h) = if max_w / aspect <= max_h {
        (max_w, max_w / aspect)
    } else {
        (max_h * aspect, max_h)
    };
    let w = (w.floor() as u32).clamp(1, f.width);
    let h = (h.floor() as u32).clamp(1, f.height);
    (w, h)
}

/// A unit's calibration in Looking Glass Factory's `visual.json` form.
///
/// `pitch`, `slope` and `center` are required; the other fields override the board only
/// when present. Keys the weave does not use (serial, fringe, verticalAngle) are ignored; a key that is
/// not a visual.json key at all is refused (see [`VISUAL_JSON_KEYS`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub origin: String,
    pub pitch: f64,
    pub slope: f64,
    pub center: f64,
    pub inv_view: Option<bool>,
    pub dpi: Option<f64>,
    pub screen_w: Option<u32>,
    pub screen_h: Option<u32>,
    pub flip_image_x: Option<bool>,
    pub flip_image_y: Option<bool>,
    pub flip_subp: Option<bool>,
    pub view_cone_deg: Option<f64>,
    pub cell_pattern: Option<CellPattern>,
    /// `Some(empty)` when the file lists no cells: a plain RGB stripe.
    pub subpixel_cells: Option<Vec<SubpixelCell>>,
}

impl Calibration {
    pub fn from_path(path: &Path) -> Result<Calibration, BoardError> {
        let text = std::fs::read_to_string(path).map_err(|source| BoardError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Calibration::from_json_str(&text, &path.display().to_string())
    }

    /// Parses `visual.json` text; `origin` names the source in error messages.
    pub fn from_json_str(text: &str, origin: &str) -> Result<Calibration, BoardError> {
        let root: serde_json::Value =
            serde_json::from_str(text).map_err(|e| BoardError::Parse {
                origin: origin.to_string(),
                message: format!("not valid JSON: {e}"),
            })?;
        let obj = root.as_object().ok_or_else(|| BoardError::Parse {
            origin: origin.to_string(),
            message: "expected a JSON object of calibration fields".into(),
        })?;
        let reader = CalReader { origin, obj };
        reader.known_keys()?;
        let cal = Calibration {
            origin: origin.to_string(),
            pitch: reader.required("pitch")?,
            slope: reader.required("slope")?,
            center: reader.required("center")?,
            inv_view: reader.flag("invView")?,
            dpi: reader.number("DPI")?,
            screen_w: reader.pixels("screenW")?,
            screen_h: reader.pixels("screenH")?,
            flip_image_x: reader.flag("flipImageX")?,
            flip_image_y: reader.flag("flipImageY")?,
            flip_subp: reader.flag("flipSubp")?,
            view_cone_deg: reader.number("viewCone")?,
            cell_pattern: reader.cell_pattern("CellPatternMode")?,
            subpixel_cells: reader.cells("subpixelCells")?,
        };
        cal.validate()?;
        Ok(cal)
    }

    fn validate(&self) -> Result<(), BoardError> {
        let v = Validator {
            origin: &self.origin,
        };
        v.positive("pitch", self.pitch)?;
        v.within("pitch", self.pitch, PITCH_RANGE)?;
        v.check(self.slope != 0.0, "slope", "must not be 0")?;
        v.magnitude("slope", self.slope, SLOPE_RANGE)?;
        v.offset("center", self.center)?;
        if let Some(dpi) = self.dpi {
            v.positive("DPI", dpi)?;
            v.within("DPI", dpi, DPI_RANGE)?;
        }
        if let Some(cone) = self.view_cone_deg {
            v.check(
                cone > 0.0 && cone < 180.0,
                "viewCone",
                &format!("must be in (0, 180) degrees, got {cone}"),
            )?;
        }
        Ok(())
    }
}

/// Reads `{"value": x}`-wrapped fields (plain numbers are accepted too).
struct CalReader<'a> {
    origin: &'a str,
    obj: &'a serde_json::Map<String, serde_json::Value>,
}

impl CalReader<'_> {
    fn err(&self, field: &str, reason: impl fmt::Display) -> BoardError {
        BoardError::Invalid {
            origin: self.origin.to_string(),
            field: field.to_string(),
            reason: reason.to_string(),
        }
    }

    /// Refuses a key that is not a visual.json key, naming the nearest one.
    fn known_keys(&self) -> Result<(), BoardError> {
        match self
            .obj
            .keys()
            .find(|k| !VISUAL_JSON_KEYS.contains(&k.as_str()))
        {
            Some(key) => Err(self.err(key, unknown_key(key, VISUAL_JSON_KEYS, "a visual.json"))),
            None => Ok(()),
        }
    }

    fn cell_pattern(&self, field: &str) -> Result<Option<CellPattern>, BoardError> {
        let Some(mode) = self.number(field)? else {
            return Ok(None);
        };
        u8::try_from(mode as i64)
            .ok()
            .filter(|_| mode.fract() == 0.0)
            .and_then(|m| CellPattern::try_from(m).ok())
            .map(Some)
            .ok_or_else(|| self.err(field, format!("must be 0, 1, 2, 3 or 4, got {mode}")))
    }

    /// `subpixelCells`: a list of objects of six offsets in pixels, bare numbers.
    fn cells(&self, field: &str) -> Result<Option<Vec<SubpixelCell>>, BoardError> {
        let Some(value) = self.obj.get(field) else {
            return Ok(None);
        };
        let list = value
            .as_array()
            .ok_or_else(|| self.err(field, format!("expected a list of cells, got {value}")))?;
        if list.len() > MAX_CELLS {
            return Err(self.err(
                field,
                format!("at most {MAX_CELLS} cells, got {}", list.len()),
            ));
        }
        list.iter()
            .enumerate()
            .map(|(i, cell)| self.cell(&format!("{field}[{i}]"), cell))
            .collect::<Result<Vec<_>, _>>()
            .map(Some)
    }

    fn cell(&self, field: &str, value: &serde_json::Value) -> Result<SubpixelCell, BoardError> {
        let obj = value.as_object().ok_or_else(|| {
            self.err(
                field,
                format!(
                    "expected an object of {}, got {value}",
                    CELL_KEYS.join(", ")
                ),
            )
        })?;
        if let Some(key) = obj.keys().find(|k| !CELL_KEYS.contains(&k.as_str())) {
            return Err(self.err(
                &format!("{field}.{key}"),
                unknown_key(key, CELL_KEYS, "a subpixel cell"),
            ));
        }
        let offset = |key: &str| {
            let name = format!("{field}.{key}");
            let v = obj
                .get(key)
                .ok_or_else(|| self.err(&name, "missing (a cell gives all six offsets)"))?;
            v.as_f64()
                .filter(|x| x.is_finite() && x.abs() <= MAX_CELL_OFFSET)
                .ok_or_else(|| {
                    self.err(
                        &name,
                        format!(
                            "expected an offset in pixels between -{MAX_CELL_OFFSET} and \
                             {MAX_CELL_OFFSET}, got {v}"
                        ),
                    )
                })
        };
        Ok(SubpixelCell {
            r: [offset("ROffsetX")?, offset("ROffsetY")?],
            g: [offset("GOffsetX")?, offset("GOffsetY")?],
            b: [offset("BOffsetX")?, offset("BOffsetY")?],
        })
    }

    fn raw(&self, field: &str) -> Result<Option<&serde_json::Value>, BoardError> {
        let Some(v) = self.obj.get(field) else {
            return Ok(None);
        };
        match v {
            serde_json::Value::Object(inner) => inner
                .get("value")
                .map(Some)
                .ok_or_else(|| self.err(field, "expected {\"value\": ...}")),
            other => Ok(Some(other)),
        }
    }

    fn number(&self, field: &str) -> Result<Option<f64>, BoardError> {
        match self.raw(field)? {
            None => Ok(None),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| self.err(field, format!("expected a number, got {v}"))),
        }
    }

    fn required(&self, field: &str) -> Result<f64, BoardError> {
        self.number(field)?
            .ok_or_else(|| self.err(field, "missing (a visual.json always has it)"))
    }

    fn flag(&self, field: &str) -> Result<Option<bool>, BoardError> {
        match self.raw(field)? {
            None => Ok(None),
            Some(serde_json::Value::Bool(b)) => Ok(Some(*b)),
            Some(v) => match v.as_f64() {
                Some(x) if x == 0.0 || x == 1.0 => Ok(Some(x == 1.0)),
                _ => Err(self.err(field, format!("expected 0, 1 or a boolean, got {v}"))),
            },
        }
    }

    fn pixels(&self, field: &str) -> Result<Option<u32>, BoardError> {
        match self.number(field)? {
            None => Ok(None),
            Some(x) if x >= 1.0 && x <= f64::from(MAX_PANEL_SIDE) && x.fract() == 0.0 => {
                Ok(Some(x as u32))
            }
            Some(x) => Err(self.err(
                field,
                format!("expected a whole number of pixels in 1..={MAX_PANEL_SIDE}, got {x}"),
            )),
        }
    }
}
