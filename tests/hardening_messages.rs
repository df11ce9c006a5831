//! What the user reads carries no Rust Debug formatting (issue 26): no `Struct { field:
//! … }`, no `Some(…)`, no variant names glued together. Before, `render -v` logged
//! `LdiStats { width: 288, … }` and the field of view's source as `Default`, and `depth`
//! on a Dynamic Depth photo said `DynamicDepth RangeLinear`.

use crate::depth_support;

use std::process::Command;

fn reshader() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_reshader"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"));
    cmd
}

/// The first piece of `text` that looks like Debug output, if any.
fn debug_formatted(text: &str) -> Option<&str> {
    for (i, _) in text.match_indices(" { ") {
        // `Name { field: …`: an identifier with a capital before, `ident:` after.
        let before = text[..i]
            .rsplit(|c: char| !c.is_alphanumeric() && c != '_')
            .next();
        let after = text[i + 3..]
            .split(|c: char| !c.is_alphanumeric() && c != '_')
            .next();
        let field_follows =
            after.is_some_and(|a| !a.is_empty() && text[i + 3 + a.len()..].starts_with(": "));
        if before.is_some_and(|b| b.starts_with(|c: char| c.is_ascii_uppercase())) && field_follows
        {
            return Some(&text[i.saturating_sub(40)..(i + 40).min(text.len())]);
        }
    }
    [
        "Some(",
        "None)",
        "Fixed(",
        "Symbol(",
        "DynamicDepth",
        "Exif35mm",
        "CommandLine)",
    ]
    .iter()
    .find_map(|p| text.find(p).map(|i| &text[i..(i + 40).min(text.len())]))
}

#[test]
fn the_checker_finds_debug_output() {
    assert!(debug_formatted("LDI built: LdiStats { width: 288, height: 384 }").is_some());
    assert!(debug_formatted("channels Some(Fixed(7))").is_some());
    assert!(debug_formatted("photo x.jpg: 288x384 (the default) { not: debug").is_none());
    assert!(debug_formatted("depth from GDepth RangeInverse, {x} y").is_none());
}

fn assert_readable(what: &str, output: &std::process::Output) {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(output.status.success(), "{what}: {text}");
    if let Some(piece) = debug_formatted(&text) {
        panic!("{what} prints Debug formatting: …{piece}…\n{text}");
    }
}

#[test]
fn render_at_info_level_logs_readable_lines() {
    let dir = tempfile::tempdir().unwrap();
    let output = reshader()
        .args(["-v", "render", "examples/pumpkin/pumpkin.jpg", "--depth"])
        .arg("examples/pumpkin/pumpkin_disparity.png")
        .args(["--depth-kind", "disparity", "--board", "generic-4view"])
        .args(["--model", "none", "--out"])
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    assert_readable("render -v", &output);
}

#[test]
fn depth_names_embedded_depth_in_words() {
    let dir = tempfile::tempdir().unwrap();
    let (png, _) = depth_support::depth_png(20, 15);
    let photo = dir.path().join("dd.jpg");
    std::fs::write(&photo, depth_support::dynamic_depth_jpeg(&png, png.len())).unwrap();
    let output = reshader()
        .args(["-v", "depth", "--depth", "embedded"])
        .arg(&photo)
        .arg("--out")
        .arg(dir.path().join("dd.npy"))
        .output()
        .unwrap();
    assert_readable("depth", &output);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("(Dynamic Depth RangeLinear"), "{stdout}");
}
