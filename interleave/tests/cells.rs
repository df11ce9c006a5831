//! Panels whose subpixels are placed by cells (Looking Glass's Spatial Displays):
//! hand-computed subpixels, the identity with the plain stripe, calibration files.

use interleave::{Board, Calibration, CellPattern, Lens, Weaver};

/// A 10x10 panel, 1 inch wide (DPI 10), slope 4/3 so that cos(atan(3/4)) = 4/5:
/// pitch' = 5 · (10/10) · 0.8 = 4 lenses across the panel, tilt = 10 / (10 · 4/3) = 0.75.
/// Its cells are the 16" Spatial Display's: cell 0 R (−0.31, +0.25), G (+0.28, +0.25),
/// B (0, −0.25); cell 1 the same with the Y offsets negated; pattern 2 picks cell
/// (row from the bottom mod 4) mod 2.
const SMALL: &str = r#"
name = "small"
width = 10
height = 10
views = 10
quilt_cols = 10
quilt_rows = 1
view_cone_deg = 40.0

[looking_glass]
pitch = 5.0
slope = 1.3333333333333333
center = 0.1
inv_view = true
dpi = 10.0
cell_pattern = 2
subpixel_cells = [
    { r = [-0.31, 0.25], g = [0.28, 0.25], b = [0.0, -0.25] },
    { r = [-0.31, -0.25], g = [0.28, -0.25], b = [0.0, 0.25] },
]
"#;

fn views_of(board: &Board, x: u32, y: u32) -> [usize; 3] {
    let m = board.mapping();
    [0, 1, 2].map(|c| m.view_index(x, y, c))
}

#[test]
fn small_panel_subpixels_by_hand() {
    let board = Board::from_toml_str(SMALL, "small.toml").unwrap();
    // Each subpixel: u = (x + 0.5 + dx)/10, v = (y_up + 0.5 + dy)/10,
    // phase = (u + 0.75·v)·4 − 0.1, t = 1 − frac(phase), view = floor(10·t).
    //
    // Bottom-left pixel (x 0, image row 9, y_up 0 → cell 0):
    //   R: u = 0.019, v = 0.075: (0.019 + 0.05625)·4 − 0.1 = 0.201 → t 0.799 → view 7
    //   G: u = 0.078, v = 0.075: (0.078 + 0.05625)·4 − 0.1 = 0.437 → t 0.563 → view 5
    //   B: u = 0.05,  v = 0.025: (0.05 + 0.01875)·4 − 0.1  = 0.175 → t 0.825 → view 8
    // (the plain stripe would put B at u + 2/30 with v = 0.05: phase 0.5167, view 4).
    assert_eq!(views_of(&board, 0, 9), [7, 5, 8]);
    // The pixel above (image row 8, y_up 1 → cell 1):
    //   R: u = 0.019, v = 0.125: (0.019 + 0.09375)·4 − 0.1 = 0.351 → t 0.649 → view 6
    //   G: u = 0.078, v = 0.125: (0.078 + 0.09375)·4 − 0.1 = 0.587 → t 0.413 → view 4
    //   B: u = 0.05,  v = 0.175: (0.05 + 0.13125)·4 − 0.1  = 0.625 → t 0.375 → view 3
    assert_eq!(views_of(&board, 0, 8), [6, 4, 3]);
    // Top row, x 3 (y_up 9 → 9 mod 4 = 1 → cell 1), u = 0.35, v = 0.95:
    //   R: u = 0.319, v = 0.925: (0.319 + 0.69375)·4 − 0.1 = 3.951 → t 0.049 → view 0
    //   G: u = 0.378, v = 0.925: (0.378 + 0.69375)·4 − 0.1 = 4.187 → t 0.813 → view 8
    //   B: u = 0.35,  v = 0.975: (0.35 + 0.73125)·4 − 0.1  = 4.225 → t 0.775 → view 7
    assert_eq!(views_of(&board, 3, 0), [0, 8, 7]);
}

#[test]
fn sixteen_inch_spatial_display_subpixels_by_hand() {
    let board = Board::builtin("looking-glass-16-spatial").unwrap();
    // 3840x2160, pitch 44.72, slope −6.9, center 0.5, DPI 283, 49 views, invView:
    //   pitch' = 44.72 · (3840/283) · cos(atan(1/−6.9))
    //          = 44.72 · 13.568905 · 0.9896606 = 600.52745 lenses across the panel
    //   tilt   = 2160 / (3840 · −6.9) = −0.0815217
    // Pixel x 1000, image row 500: y_up = 2159 − 500 = 1659, 1659 mod 4 = 3, mod 2 = 1
    // → cell 1: R (−0.31, −0.25), G (+0.28, −0.25), B (0, +0.25).
    //   R: u = 1000.19/3840 = 0.2604661, v = 1659.25/2160 = 0.7681713, v·tilt = −0.0626227
    //      (u + v·tilt)·pitch' = 0.1978435 · 600.52745 = 118.810444, − 0.5 → frac 0.310444
    //      t = 0.689556, 49·t = 33.79 → view 33
    //   G: u = 1000.78/3840 = 0.2606198, same v: 0.1979971 · 600.52745 = 118.902713
    //      − 0.5 → frac 0.402713, t = 0.597287, 49·t = 29.27 → view 29
    //   B: u = 1000.5/3840 = 0.2605469, v = 1659.75/2160 = 0.7684028, v·tilt = −0.0626415
    //      0.1979053 · 600.52745 = 118.847592, − 0.5 → frac 0.347592, t = 0.652408,
    //      49·t = 31.97 → view 31
    // The plain stripe's formula gives 31, 29, 26 here: red and blue would be wrong.
    assert_eq!(views_of(&board, 1000, 500), [33, 29, 31]);
}

#[test]
fn stripe_cells_reproduce_the_plain_formula() {
    // One cell putting R at the pixel centre, G a third and B two thirds of a pixel to
    // the right is exactly the plain RGB stripe.
    let plain = r#"
name = "p"
width = 40
height = 30
views = 48
quilt_cols = 8
quilt_rows = 6
view_cone_deg = 40.0
[looking_glass]
pitch = 52.0
slope = -7.0
center = 0.43
inv_view = true
dpi = 324.0
"#;
    let cells = format!(
        "{plain}subpixel_cells = [{{ r = [0.0, 0.0], g = [{:?}, 0.0], b = [{:?}, 0.0] }}]\n",
        1.0 / 3.0,
        2.0 / 3.0
    );
    let a = Board::from_toml_str(plain, "p.toml").unwrap().mapping();
    let b = Board::from_toml_str(&cells, "c.toml").unwrap().mapping();
    for y in 0..30 {
        for x in 0..40 {
            for c in 0..3 {
                let (ta, tb) = (a.cone_position(x, y, c), b.cone_position(x, y, c));
                assert!((ta - tb).abs() < 1e-9, "({x}, {y}, {c}): {ta} vs {tb}");
            }
        }
    }
}

#[test]
fn weaving_table_matches_the_mapping_on_every_subpixel() {
    let board = Board::from_toml_str(SMALL, "small.toml").unwrap();
    let m = board.mapping();
    let weaver = Weaver::new(&board, 5, 5);
    for y in 0..10 {
        for x in 0..10 {
            for c in 0..3 {
                assert_eq!(
                    weaver.view_at(x, y, c),
                    m.view_index(x, y, c),
                    "({x},{y},{c})"
                );
            }
        }
    }
}

/// A 16" Spatial Display's visual.json as Looking Glass writes it.
const SPATIAL_JSON: &str = r#"{
  "configVersion": "3.0", "serial": "LKG-J00000",
  "pitch": {"value": 44.72}, "slope": {"value": -6.9}, "center": {"value": 0.5},
  "fringe": {"value": 0.0}, "viewCone": {"value": 50.0}, "invView": {"value": 1.0},
  "verticalAngle": {"value": 0.0}, "DPI": {"value": 283.0},
  "screenW": {"value": 3840.0}, "screenH": {"value": 2160.0},
  "flipImageX": {"value": 0.0}, "flipImageY": {"value": 0.0}, "flipSubp": {"value": 0.0},
  "CellPatternMode": {"value": 2},
  "subpixelCells": [
    {"ROffsetX": -0.31, "ROffsetY": 0.25, "GOffsetX": 0.28, "GOffsetY": 0.25,
     "BOffsetX": 0.0, "BOffsetY": -0.25},
    {"ROffsetX": -0.31, "ROffsetY": -0.25, "GOffsetX": 0.28, "GOffsetY": -0.25,
     "BOffsetX": 0.0, "BOffsetY": 0.25}
  ]
}"#;

#[test]
fn a_spatial_display_calibration_carries_its_cells() {
    let cal = Calibration::from_json_str(SPATIAL_JSON, "visual.json").unwrap();
    assert_eq!(cal.cell_pattern, Some(CellPattern::FourRows));
    let cells = cal.subpixel_cells.clone().unwrap();
    assert_eq!(cells.len(), 2);
    assert_eq!((cells[1].r, cells[1].b), ([-0.31, -0.25], [0.0, 0.25]));
    // On a board that had no cells, the calibration brings them: the same cone positions
    // as the built-in board with the same values.
    let mut board = Board::builtin("looking-glass-16-gen2").unwrap();
    board.apply_calibration(&cal).unwrap();
    let (calibrated, spatial) = (
        board.mapping(),
        Board::builtin("looking-glass-16-spatial")
            .unwrap()
            .mapping(),
    );
    for (x, y) in [(0, 0), (1000, 500), (3839, 2159), (1234, 77)] {
        for c in 0..3 {
            let (a, b) = (
                calibrated.cone_position(x, y, c),
                spatial.cone_position(x, y, c),
            );
            assert_eq!(a, b, "({x}, {y}, {c})");
        }
    }
    // A unit whose file lists no cells is a plain stripe, even on a board that had cells.
    let stripe = SPATIAL_JSON.replace("\"CellPatternMode\": {\"value\": 2},", "");
    let start = stripe.find("\"subpixelCells\"").unwrap();
    let stripe = format!("{}\"subpixelCells\": []}}", &stripe[..start]);
    let mut board = Board::builtin("looking-glass-16-spatial").unwrap();
    board
        .apply_calibration(&Calibration::from_json_str(&stripe, "v.json").unwrap())
        .unwrap();
    let Lens::LookingGlass(lg) = board.lens() else {
        panic!("a Looking Glass board");
    };
    assert!(lg.subpixel_cells.is_empty());
}

#[test]
fn cell_errors_name_the_cell_and_key() {
    let err = |json: String| {
        Calibration::from_json_str(&json, "unit/visual.json")
            .expect_err("calibration should be refused")
            .to_string()
    };
    let typo = err(SPATIAL_JSON.replacen("\"GOffsetY\": 0.25", "\"GOfsetY\": 0.25", 1));
    assert!(
        typo.contains(
            "unit/visual.json: field `subpixelCells[0].GOfsetY`: unknown key; did you mean \
             `GOffsetY`?"
        ),
        "{typo}"
    );
    let missing = err(SPATIAL_JSON.replacen(", \"BOffsetY\": 0.25}", "}", 1));
    assert!(
        missing.contains("field `subpixelCells[1].BOffsetY`: missing"),
        "{missing}"
    );
    let far = err(SPATIAL_JSON.replacen("\"ROffsetX\": -0.31", "\"ROffsetX\": -31", 1));
    assert!(
        far.contains("field `subpixelCells[0].ROffsetX`: expected an offset in pixels"),
        "{far}"
    );
    let mode = err(SPATIAL_JSON.replace("{\"value\": 2}", "{\"value\": 7}"));
    assert!(
        mode.contains("field `CellPatternMode`: must be 0, 1, 2, 3 or 4, got 7"),
        "{mode}"
    );
    let not_list = err(SPATIAL_JSON
        .replace("\"subpixelCells\": [", "\"subpixelCells\": {\"a\": [")
        .replace("]\n}", "]}\n}"));
    assert!(not_list.contains("expected a list of cells"), "{not_list}");

    // The same checks in a board file, named in the board's terms.
    let bad = SMALL.replace("r = [-0.31, 0.25]", "r = [-31.0, 0.25]");
    let e = Board::from_toml_str(&bad, "boards/x.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("boards/x.toml: field `looking_glass.subpixel_cells[0].r`"),
        "{e}"
    );
    let bad = SMALL.replace("cell_pattern = 2", "cell_pattern = 9");
    let e = Board::from_toml_str(&bad, "boards/x.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cell pattern must be 0, 1, 2, 3 or 4, got 9"),
        "{e}"
    );
    let bad = SMALL.replace("g = [0.28, 0.25]", "gg = [0.28, 0.25]");
    let e = Board::from_toml_str(&bad, "boards/x.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown field `gg`"), "{e}");
}
