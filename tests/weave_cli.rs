//! `reshader weave`: view filtering chosen by the board and overridden on the command line.

mod spine_support;

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
