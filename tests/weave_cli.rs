//! `reshader weave`: view filtering chosen by the board and overridden on the command line.

use crate::spine_support;

use std::path::Path;

use spine_support::*;

fn weave(out: &Path, board: &str, extra: &[&str]) -> std::process::Output {
    let views = golden_dir().join("views").display().to_string();
    let out = out.display().to_string();
    let mut args = vec!["weave", &views, "--board", board, "--out", &out];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn the_board_chooses_the_filter_and_the_command_line_overrides_it() {
    let tmp = tempfile::tempdir().unwrap();
    let golden_panel = load(&golden_dir().join("panel.png"));

    let gaussian = tmp.path().join("gaussian.png");
    let result = weave(&gaussian, &tiny_board(), &["--blend", "gaussian"]);
    assert!(result.status.success(), "{}", stderr(&result));
    let gaussian = load(&gaussian);
    assert_eq!(gaussian.dimensions(), golden_panel.dimensions());
    assert!(
        gaussian != golden_panel,
        "the Gaussian mixes neighbouring views"
    );

    // The same filter from a board file's [filter] table.
    let text = std::fs::read_to_string(tiny_board()).unwrap();
    let board = tmp.path().join("soft.toml");
    std::fs::write(&board, format!("{text}\n[filter]\nblend = \"gaussian\"\n")).unwrap();
    let board = board.display().to_string();
    let from_board = tmp.path().join("from_board.png");
    let result = weave(&from_board, &board, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&from_board) == gaussian);

    // --blend nearest on that board gives the plain weave back.
    let nearest = tmp.path().join("nearest.png");
    let result = weave(&nearest, &board, &["--blend", "nearest"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&nearest) == golden_panel);

    // Dimming darkens: no subpixel brighter than undimmed, some darker.
    let dimmed = tmp.path().join("dimmed.png");
    let result = weave(
        &dimmed,
        &board,
        &["--blend", "nearest", "--dim-edges", "0.2"],
    );
    assert!(result.status.success(), "{}", stderr(&result));
    let dimmed = load(&dimmed);
    let pairs: Vec<(u8, u8)> = dimmed
        .as_raw()
        .iter()
        .copied()
        .zip(golden_panel.as_raw().iter().copied())
        .collect();
    assert!(pairs.iter().all(|(d, p)| d <= p));
    assert!(pairs.iter().any(|(d, p)| d < p));
}

#[test]
fn a_bad_filter_is_refused_in_words() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("panel.png");
    let result = weave(&out, &tiny_board(), &["--dim-edges", "0.9"]);
    let err = stderr(&result);
    assert_eq!(result.status.code(), Some(1), "{err}");
    assert!(
        err.contains("filter.dim_edges") && err.contains("between 0 and 0.5, got 0.9"),
        "{err}"
    );
    assert!(!out.exists());
    let result = weave(&out, &tiny_board(), &["--blend", "cubic"]);
    assert!(!result.status.success());
    assert!(stderr(&result).contains("gaussian"), "{}", stderr(&result));
}

/// Renders the tiny scene's quilt and panel into `dir/out`; returns the quilt's path.
fn render_quilt(dir: &Path) -> std::path::PathBuf {
    let (photo, depth) = write_scene(dir);
    let out = dir.join("out");
    let out_s = out.display().to_string();
    let board = tiny_board();
    let result = run(&[
        "render",
        &photo,
        "--depth",
        &depth,
        "--board",
        &board,
        "--only",
        "quilt,panel",
        "--out",
        &out_s,
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    out.join("quilt_qs3x2a1.5.png")
}

fn png_text(path: &Path) -> Vec<(String, String)> {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let reader = png::Decoder::new(file).read_info().unwrap();
    reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .map(|t| (t.keyword.clone(), t.text.clone()))
        .collect()
}

/// Writes `image` as a PNG with exactly the text chunks `text`.
fn write_png(path: &Path, image: &image::RgbImage, text: &[(&str, &str)]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut encoder = png::Encoder::new(file, image.width(), image.height());
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    for (k, v) in text {
        encoder
            .add_text_chunk(k.to_string(), v.to_string())
            .unwrap();
    }
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(image.as_raw()).unwrap();
}

fn weave_file(input: &Path, out: &Path) -> std::process::Output {
    let (input, out) = (input.display().to_string(), out.display().to_string());
    let board = tiny_board();
    run(&["weave", &input, "--board", &board, "--out", &out])
}

#[test]
fn a_quilt_carries_its_layout_and_weaves_back_into_the_panel() {
    let tmp = tempfile::tempdir().unwrap();
    let quilt = render_quilt(tmp.path());
    let text = png_text(&quilt);
    for (key, value) in [
        ("Quilt views", "6"),
        ("Quilt columns", "3"),
        ("Quilt rows", "2"),
        ("Quilt aspect", "1.5"),
    ] {
        assert!(
            text.iter().any(|(k, v)| k == key && v == value),
            "{key} = {value} missing from {text:?}"
        );
    }
    let panel = load(&tmp.path().join("out/panel.png"));

    // From the metadata.
    let woven = tmp.path().join("from_quilt.png");
    let result = weave_file(&quilt, &woven);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(
        load(&woven) == panel,
        "the quilt weaves into render's panel"
    );

    // From the name alone, as other software writes quilts.
    let image = load(&quilt);
    let named = tmp.path().join("elsewhere_qs3x2a1.5.png");
    write_png(&named, &image, &[]);
    let woven = tmp.path().join("from_name.png");
    let result = weave_file(&named, &woven);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&woven) == panel);

    // Metadata alone (a name without the layout).
    let tagged = tmp.path().join("tagged.png");
    write_png(
        &tagged,
        &image,
        &[("Quilt columns", "3"), ("Quilt rows", "2")],
    );
    let woven = tmp.path().join("from_metadata.png");
    let result = weave_file(&tagged, &woven);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(load(&woven) == panel);
}

/// A quilt file's name, its text chunks, and what the error must say.
type Case<'a> = (&'a str, &'a [(&'a str, &'a str)], &'a [&'a str]);

#[test]
fn a_quilt_without_or_with_wrong_metadata_is_refused_in_words() {
    let tmp = tempfile::tempdir().unwrap();
    let image = load(&render_quilt(tmp.path()));
    let cases: [Case; 5] = [
        (
            "plain.png",
            &[],
            &["plain.png", "no quilt layout", "qs{cols}x{rows}a{aspect}"],
        ),
        (
            "rows.png",
            &[("Quilt columns", "3"), ("Quilt rows", "six")],
            &["rows.png", "metadata `Quilt rows`", "got `six`"],
        ),
        (
            "grid_qs2x3a1.5.png",
            &[("Quilt columns", "3"), ("Quilt rows", "2")],
            &["the metadata says 3x2 but the name says 2x3"],
        ),
        (
            "uneven.png",
            &[("Quilt columns", "5"), ("Quilt rows", "2")],
            &["uneven.png", "72x32 image does not divide into 5x2 tiles"],
        ),
        (
            "eight.png",
            &[("Quilt columns", "4"), ("Quilt rows", "2")],
            &["eight.png", "holds 8 views but board `tiny-test` shows 6"],
        ),
    ];
    for (name, text, needles) in cases {
        let input = tmp.path().join(name);
        write_png(&input, &image, text);
        let out = tmp.path().join(format!("panel-{name}"));
        let result = weave_file(&input, &out);
        let err = stderr(&result);
        assert_eq!(result.status.code(), Some(1), "{name}: {err}");
        for needle in needles {
            assert!(err.contains(needle), "{name}: expected {needle:?} in {err}");
        }
        assert!(!out.exists(), "{name}: nothing is written");
    }
}
