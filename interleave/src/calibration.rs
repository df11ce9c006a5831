//! A unit's calibration in Looking Glass Factory's `visual.json` form, read strictly:
//! a misspelt key is refused with the nearest real one.

use std::fmt;
use std::path::Path;

use crate::cells::{CellPattern, SubpixelCell, MAX_CELLS, MAX_CELL_OFFSET};
use crate::validate::{
    unknown_key, BoardError, Validator, DPI_RANGE, MAX_PANEL_SIDE, PITCH_RANGE, SLOPE_RANGE,
};

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

/// The keys of one `subpixelCells` entry: each colour's offset in pixels.
const CELL_KEYS: &[&str] = &[
    "ROffsetX", "ROffsetY", "GOffsetX", "GOffsetY", "BOffsetX", "BOffsetY",
];

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
