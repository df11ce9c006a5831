//! Board files, built-in boards and calibration files: loading and error messages.

use std::path::Path;

use interleave::{Board, BoardError, Calibration, Lens};

const GOOD: &str = r#"
name = "mine"
width = 1536
height = 2048
views = 48
quilt_cols = 8
quilt_rows = 6
view_cone_deg = 40.0

[looking_glass]
pitch = 52.0
slope = -7.0
center = 0.5
inv_view = true
dpi = 324.0
"#;

fn error_for(text: &str) -> String {
    Board::from_toml_str(text, "boards/x.toml")
        .expect_err("board should be rejected")
        .to_string()
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn every_shipped_board_loads_with_its_documented_values() {
    let expected = [
        ("looking-glass-portrait", (1536, 2048), 48, (8, 6), 40.0),
        ("looking-glass-go", (1440, 2560), 66, (11, 6), 54.0),
        ("looking-glass-16-gen2", (3840, 2160), 45, (5, 9), 40.0),
        ("looking-glass-16-spatial", (3840, 2160), 49, (7, 7), 50.0),
        (
            "looking-glass-16-spatial-portrait",
            (2160, 3840),
            66,
            (11, 6),
            50.0,
        ),
        ("looking-glass-32-spatial", (7680, 4320), 49, (7, 7), 50.0),
        (
            "looking-glass-32-spatial-portrait",
            (4320, 7680),
            66,
            (11, 6),
            54.0,
        ),
        ("generic-8view", (1920, 1080), 8, (4, 2), 30.0),
        ("generic-4view", (1920, 1080), 4, (2, 2), 20.0),
        ("sbs-2view", (1920, 1080), 2, (2, 1), 6.0),
    ];
    assert_eq!(Board::builtin_names().len(), expected.len());
    for (name, size, views, grid, cone) in expected {
        let b = Board::builtin(name).unwrap();
        assert_eq!(b.name(), name);
        assert_eq!(b.panel_size(), size, "{name}");
        assert_eq!(b.views(), views, "{name}");
        assert_eq!(b.quilt_grid(), grid, "{name}");
        assert_eq!(b.view_cone_deg(), cone, "{name}");
        let (vw, vh) = b.view_size();
        assert!(vw > 0 && vh > 0 && vw <= size.0 && vh <= size.1, "{name}");
        assert!(Board::builtin_names().contains(&name));
        // The files in boards/ are the ones embedded in the library.
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../boards")
            .join(format!("{name}.toml"));
        assert_eq!(Board::from_path(&path).unwrap().panel_size(), size);
    }
}

#[test]
fn looking_glass_boards_carry_the_issue_values() {
    let cases = [
        ("looking-glass-portrait", 52.0, -7.0, 0.5, 324.0),
        ("looking-glass-go", 80.7, -6.3, -0.3, 491.0),
        ("looking-glass-16-gen2", 50.0, -7.0, 0.5, 283.0),
        ("looking-glass-16-spatial", 44.72, -6.9, 0.5, 283.0),
        (
            "looking-glass-16-spatial-portrait",
            44.72,
            -7.45,
            0.0,
            283.0,
        ),
        ("looking-glass-32-spatial", 75.0, -7.2, -0.2, 280.0),
        ("looking-glass-32-spatial-portrait", 80.7, -6.3, -0.3, 280.0),
    ];
    for (name, pitch, slope, center, dpi) in cases {
        let Lens::LookingGlass(lg) = Board::builtin(name).unwrap().lens().clone() else {
            panic!("{name} should be in Looking-Glass form");
        };
        assert_eq!(
            (lg.pitch, lg.slope, lg.center, lg.dpi),
            (pitch, slope, center, dpi)
        );
        assert!(lg.inv_view);
    }
    assert_eq!(
        Board::builtin("looking-glass-portrait")
            .unwrap()
            .view_size(),
        (420, 560)
    );
}

#[test]
fn a_board_chooses_its_view_filter() {
    use interleave::{Blend, ViewFilter};
    assert_eq!(
        Board::from_toml_str(GOOD, "x.toml").unwrap().filter(),
        ViewFilter::default()
    );
    let text = format!("{GOOD}\n[filter]\nblend = \"gaussian\"\nsigma = 0.7\ndim_edges = 0.1\n");
    let filter = Board::from_toml_str(&text, "x.toml").unwrap().filter();
    assert_eq!(
        filter,
        ViewFilter {
            blend: Blend::Gaussian,
            sigma: 0.7,
            dim_edges: 0.1
        }
    );
    let err = error_for(&format!("{GOOD}\n[filter]\nblend = \"gausian\"\n"));
    assert!(err.contains("unknown variant `gausian`"), "{err}");
    let err = error_for(&format!("{GOOD}\n[filter]\nsigma = 5.0\n"));
    assert!(
        err.contains("field `filter.sigma`: must be between 0.1 and 2"),
        "{err}"
    );
    let err = error_for(&format!("{GOOD}\n[filter]\ndim_edges = 0.7\n"));
    assert!(err.contains("field `filter.dim_edges`"), "{err}");
    let err = error_for(&format!("{GOOD}\n[filter]\ndim_edge = 0.1\n"));
    assert!(err.contains("unknown field `dim_edge`"), "{err}");
    // A command-line override is checked the same way.
    let mut board = Board::from_toml_str(GOOD, "x.toml").unwrap();
    let err = board
        .set_filter(ViewFilter {
            dim_edges: -1.0,
            ..ViewFilter::default()
        })
        .unwrap_err()
        .to_string();
    assert!(err.contains("filter.dim_edges"), "{err}");
}

#[test]
fn resolve_takes_names_and_paths_and_lists_known_names() {
    assert_eq!(Board::resolve("sbs-2view").unwrap().views(), 2);
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "mine.toml", GOOD);
    assert_eq!(
        Board::resolve(path.to_str().unwrap()).unwrap().name(),
        "mine"
    );

    let err = Board::resolve("looking-glass-portriat")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("unknown board `looking-glass-portriat`"),
        "{err}"
    );
    for name in Board::builtin_names() {
        assert!(err.contains(name), "{err}");
    }

    let missing = dir.path().join("nope.toml");
    let err = Board::resolve(missing.to_str().unwrap()).unwrap_err();
    assert!(matches!(err, BoardError::Io { .. }));
    assert!(err.to_string().contains("nope.toml"), "{err}");
}

#[test]
fn typo_in_a_field_name_is_caught_with_file_and_field() {
    let err = error_for(&GOOD.replace("pitch = 52.0", "pitchh = 52.0"));
    assert!(err.starts_with("boards/x.toml:"), "{err}");
    assert!(err.contains("unknown field `pitchh`"), "{err}");
    let err = error_for(&GOOD.replace("views = 48", "veiws = 48"));
    assert!(err.contains("unknown field `veiws`"), "{err}");
}

#[test]
fn missing_fields_are_named() {
    let err = error_for(&GOOD.replace("views = 48\n", ""));
    assert!(err.starts_with("boards/x.toml:"), "{err}");
    assert!(err.contains("missing field `views`"), "{err}");
    let err = error_for(&GOOD.replace("dpi = 324.0\n", ""));
    assert!(err.contains("missing field `dpi`"), "{err}");
}

#[test]
fn bad_values_are_named_with_the_reason() {
    let cases = [
        (
            "pitch = 52.0",
            "pitch = 0.0",
            "field `looking_glass.pitch`: must be > 0",
        ),
        (
            "dpi = 324.0",
            "dpi = -3.0",
            "field `looking_glass.dpi`: must be > 0",
        ),
        (
            "slope = -7.0",
            "slope = 0.0",
            "field `looking_glass.slope`: must not be 0",
        ),
        (
            "width = 1536",
            "width = 0",
            "field `width`: must be between 1",
        ),
        (
            "views = 48",
            "views = 1",
            "field `views`: must be between 2 and 256",
        ),
        (
            "views = 48",
            "views = 49",
            "field `quilt_rows`: a 8x6 quilt has room for 48",
        ),
        (
            "view_cone_deg = 40.0",
            "view_cone_deg = 190.0",
            "field `view_cone_deg`",
        ),
        (
            "name = \"mine\"",
            "name = \" \"",
            "field `name`: must not be empty",
        ),
        ("width = 1536", "width = -5", "boards/x.toml:"),
        ("width = 1536", "width = \"wide\"", "invalid type"),
    ];
    for (from, to, want) in cases {
        let err = error_for(&GOOD.replace(from, to));
        assert!(err.contains(want), "{to}: {err}");
        assert!(err.starts_with("boards/x.toml:"), "{to}: {err}");
    }
}

#[test]
fn lens_tables_must_be_exactly_one() {
    let no_lens = GOOD.split("[looking_glass]").next().unwrap().to_string();
    let err = error_for(&no_lens);
    assert!(err.contains("no lens description"), "{err}");
    let two = format!("{GOOD}\n[side_by_side]\n");
    assert!(error_for(&two).contains("more than one lens description"));

    let sbs3 = format!("{no_lens}\n[side_by_side]\n");
    let err = error_for(&sbs3);
    assert!(
        err.contains("field `views`: a side-by-side board shows exactly 2"),
        "{err}"
    );

    let vb = |body: &str| format!("{no_lens}\n[van_berkel]\n{body}\n");
    let err = error_for(&vb("lens_pitch = 8.0"));
    assert!(
        err.contains("field `van_berkel.slant_deg`: missing"),
        "{err}"
    );
    let err = error_for(&vb("lens_pitch = 8.0\nslant_deg = 18.4\ntan_slant = 0.33"));
    assert!(err.contains("not both"), "{err}");
    let err = error_for(&vb("lens_pitch = 0.0\ntan_slant = 0.33"));
    assert!(
        err.contains("field `van_berkel.lens_pitch`: must be > 0"),
        "{err}"
    );
    let err = error_for(&vb("lens_pitch = 8.0\nslant_deg = 95.0"));
    assert!(err.contains("field `van_berkel.slant_deg`"), "{err}");
}

#[test]
fn view_size_defaults_to_a_quilt_that_fits_4096() {
    let b = Board::from_toml_str(GOOD, "x.toml").unwrap();
    let (w, h) = b.view_size();
    // 8x6 tiles of the panel's 3:4 aspect: 4096/8 = 512 wide would need 683 rows > 4096/6.
    assert!(w * 8 <= 4096 && h * 6 <= 4096, "{w}x{h}");
    assert!((w as f32 / h as f32 - 0.75).abs() < 0.01, "{w}x{h}");
    assert!(h >= 680, "{w}x{h}");
    let err = error_for(&GOOD.replace("views = 48", "views = 48\nview_width = 400"));
    assert!(
        err.contains("field `view_height`: must be given with `view_width`"),
        "{err}"
    );
}

const VISUAL_JSON: &str = r#"{
    "configVersion": "3.0",
    "serial": "LKG-PORT-00000",
    "pitch": {"value": 52.58737564086914},
    "slope": {"value": -7.196136474609375},
    "center": {"value": 0.4321881234645844},
    "fringe": {"value": 0.0},
    "viewCone": {"value": 40.0},
    "invView": {"value": 1.0},
    "verticalAngle": {"value": 0.0},
    "DPI": {"value": 324.0},
    "screenW": {"value": 1536.0},
    "screenH": {"value": 2048.0},
    "flipImageX": {"value": 0.0},
    "flipImageY": {"value": 0.0},
    "flipSubp": {"value": 0.0}
}"#;

#[test]
fn visual_json_is_parsed_and_applied() {
    let cal = Calibration::from_json_str(VISUAL_JSON, "visual.json").unwrap();
    assert_eq!(cal.pitch, 52.58737564086914);
    assert_eq!(cal.slope, -7.196136474609375);
    assert_eq!(cal.inv_view, Some(true));
    assert_eq!(cal.flip_subp, Some(false));
    assert_eq!((cal.screen_w, cal.screen_h), (Some(1536), Some(2048)));

    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "visual.json", VISUAL_JSON);
    let nominal = Board::builtin("looking-glass-portrait").unwrap();
    let mut board = nominal.clone();
    board.apply_calibration_file(&path).unwrap();
    let Lens::LookingGlass(lg) = board.lens() else {
        panic!("still Looking-Glass form")
    };
    assert_eq!(lg.center, 0.4321881234645844);
    assert!(board.origin().contains("visual.json"));
    // The unit's calibration moves views around.
    let (a, b) = (nominal.mapping(), board.mapping());
    let moved = (0..200)
        .filter(|&x| a.view_index(x * 7, 1000, 0) != b.view_index(x * 7, 1000, 0))
        .count();
    assert!(moved > 50, "only {moved} of 200 subpixels changed view");
}

#[test]
fn calibration_screen_size_and_partial_fields() {
    let json = r#"{"pitch": 50.1, "slope": {"value": -7}, "center": {"value": 0.1},
                  "screenW": {"value": 3840}, "screenH": {"value": 2160}, "flipSubp": true}"#;
    let cal = Calibration::from_json_str(json, "cal.json").unwrap();
    assert_eq!(cal.pitch, 50.1);
    assert_eq!(cal.dpi, None);
    let mut b = Board::builtin("looking-glass-16-gen2").unwrap();
    b.apply_calibration(&cal).unwrap();
    let Lens::LookingGlass(lg) = b.lens() else {
        panic!()
    };
    assert_eq!(lg.dpi, 283.0, "absent fields keep the board's value");
    assert!(lg.flip_subp);
}

#[test]
fn calibration_errors_name_file_and_field() {
    let cases = [
        ("{", "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        (
            r#"{"slope": {"value": -7}, "center": {"value": 0.5}}"#,
            "field `pitch`: missing",
        ),
        (
            r#"{"pitch": {"value": "52"}, "slope": -7, "center": 0.5}"#,
            "field `pitch`: expected a number",
        ),
        (
            r#"{"pitch": {"val": 52}, "slope": -7, "center": 0.5}"#,
            "field `pitch`: expected {\"value\": ...}",
        ),
        (
            r#"{"pitch": -52, "slope": -7, "center": 0.5}"#,
            "field `pitch`: must be > 0",
        ),
        (
            r#"{"pitch": 52, "slope": -7, "center": 0.5, "invView": 0.5}"#,
            "field `invView`: expected 0, 1 or a boolean",
        ),
        (
            r#"{"pitch": 52, "slope": -7, "center": 0.5, "screenW": 1536.5}"#,
            "field `screenW`: expected a whole number",
        ),
        (
            r#"{"pitch": 52, "slope": -7, "center": 0.5, "DPI": 0}"#,
            "field `DPI`: must be > 0",
        ),
    ];
    for (json, want) in cases {
        let err = Calibration::from_json_str(json, "unit/visual.json")
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("unit/visual.json:"), "{err}");
        assert!(err.contains(want), "{json}: {err}");
    }
    let missing = Path::new("/nonexistent/visual.json");
    let mut b = Board::builtin("looking-glass-go").unwrap();
    let err = b.apply_calibration_file(missing).unwrap_err().to_string();
    assert!(err.contains("/nonexistent/visual.json"), "{err}");
}

#[test]
fn calibration_only_applies_to_looking_glass_boards() {
    let cal = Calibration::from_json_str(VISUAL_JSON, "visual.json").unwrap();
    let mut b = Board::builtin("generic-8view").unwrap();
    let err = b.apply_calibration(&cal).unwrap_err().to_string();
    assert!(err.contains("visual.json"), "{err}");
    assert!(err.contains("generic-8view"), "{err}");
}

#[test]
fn absurd_calibration_values_are_refused_by_name() {
    let base = |field: &str, value: &str| {
        let mut fields = vec![
            ("pitch", "52"),
            ("slope", "-7"),
            ("center", "0.5"),
            ("DPI", "324"),
        ];
        for f in &mut fields {
            if f.0 == field {
                f.1 = value;
            }
        }
        let body: Vec<String> = fields
            .iter()
            .map(|(k, v)| format!("\"{k}\": {{\"value\": {v}}}"))
            .collect();
        format!("{{{}}}", body.join(", "))
    };
    for (field, value) in [
        ("pitch", "1e300"),
        ("pitch", "1e-300"),
        ("slope", "1e-300"),
        ("slope", "-1e300"),
        ("center", "1e300"),
        ("DPI", "1e300"),
    ] {
        let err = Calibration::from_json_str(&base(field, value), "unit/visual.json")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("field `{field}`: must be between")),
            "{field} = {value}: {err}"
        );
    }
    assert!(Calibration::from_json_str(&base("slope", "6.3"), "v.json").is_ok());
    // The same bounds hold in a board file.
    let err = error_for(&GOOD.replace("pitch = 52.0", "pitch = 1e300"));
    assert!(
        err.contains("field `looking_glass.pitch`: must be between"),
        "{err}"
    );
    let err = error_for(&GOOD.replace("slope = -7.0", "slope = -1e-300"));
    assert!(err.contains("looking_glass.slope"), "{err}");
}

#[test]
fn unknown_calibration_keys_are_refused_with_the_nearest_known_one() {
    let with = |extra: &str| format!(r#"{{"pitch": 52, "slope": -7, "center": 0.5, {extra}}}"#);
    let err = Calibration::from_json_str(&with(r#""invVeiw": {"value": 1}"#), "unit/visual.json")
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("unit/visual.json:"), "{err}");
    assert!(
        err.contains("field `invVeiw`: unknown key; did you mean `invView`?"),
        "{err}"
    );
    let err = Calibration::from_json_str(&with(r#""dpi": 324"#), "v.json")
        .unwrap_err()
        .to_string();
    assert!(err.contains("did you mean `DPI`?"), "{err}");
    let err = Calibration::from_json_str(&with(r#""zzzzzzzzzzzzzz": 1"#), "v.json")
        .unwrap_err()
        .to_string();
    assert!(err.contains("a visual.json holds configVersion"), "{err}");
    // Every key of a unit's file, used or not, is known.
    assert!(Calibration::from_json_str(VISUAL_JSON, "visual.json").is_ok());
    assert!(Calibration::from_json_str(
        &with(r#""CellPatternMode": {"value": 0}, "subpixelCells": []"#),
        "v.json"
    )
    .is_ok());
}
