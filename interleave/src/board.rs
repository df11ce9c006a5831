//! Panel descriptions ("boards"): TOML files, built-in boards and per-unit calibration.
//!
//! A board names the panel's native resolution, how many views it shows, how those views
//! are packed into a quilt, and how its lens sheet maps subpixels to views. The lens sheet
//! is given in one of three forms (Looking-Glass calibration values, van Berkel's slanted
//! lenticular parameters, or plain side-by-side stereo); [`Board::mapping`] reduces all of
//! them to one [`Mapping`].

use std::path::Path;

use serde::Deserialize;

use crate::calibration::Calibration;
use crate::filter::ViewFilter;
use crate::lens::{Lens, LookingGlass, SideBySide, SubpixelLayout, VanBerkel};
use crate::mapping::{LensPhase, Mapping};
use crate::validate::{BoardError, Validator, MAX_VIEWS};

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

impl Validator<'_> {
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
