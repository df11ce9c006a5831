//! Progress bars (issue 22): drawn on a terminal, never when stderr is piped (as here),
//! in `--json` mode or with `-v`. The terminal cases run under util-linux `script`,
//! which gives the command a pseudo-terminal; they are skipped where it is missing.

use crate::spine_support;

use std::path::Path;
use std::process::Command;

use spine_support::*;

/// What a bar leaves in a stream: carriage returns, escape sequences, its frame.
fn has_bar(text: &str) -> bool {
    text.contains('\r') || text.contains('\x1b') || text.contains("] 0/")
}

/// `reshader ARGS` with stdout and stderr on a pseudo-terminal; None without `script`.
fn on_terminal(args: &[&str]) -> Option<String> {
    let script = Path::new("/usr/bin/script");
    if !script.exists() {
        eprintln!("no /usr/bin/script: terminal cases skipped");
        return None;
    }
    let command: Vec<String> = std::iter::once(env!("CARGO_BIN_EXE_reshader"))
        .chain(args.iter().copied())
        .map(|a| format!("'{a}'"))
        .collect();
    let out = Command::new(script)
        .args(["-qec", &command.join(" "), "/dev/null"])
        .env("RESHADER_MODEL", "none")
        .env("TERM", "xterm")
        .output()
        .expect("script runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

struct Scene {
    dir: tempfile::TempDir,
    photo: String,
    depth: String,
}

impl Scene {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let (photo, depth) = write_scene(dir.path());
        Self { dir, photo, depth }
    }

    fn render_args(&self, out: &str) -> Vec<String> {
        [
            "render",
            &self.photo,
            "--depth",
            &self.depth,
            "--board",
            &tiny_board(),
            "--out",
            &self.dir.path().join(out).display().to_string(),
        ]
        .map(String::from)
        .to_vec()
    }

    /// A gallery of one photo with its depth sidecar.
    fn gallery(&self) -> String {
        let gallery = self.dir.path().join("gallery");
        std::fs::create_dir_all(&gallery).unwrap();
        std::fs::copy(&self.photo, gallery.join("a.png")).unwrap();
        std::fs::copy(&self.depth, gallery.join("a_depth.npy")).unwrap();
        gallery.join("a.png").display().to_string()
    }
}

fn strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

#[test]
fn piped_output_has_no_bar() {
    let scene = Scene::new();
    let render = run(&strs(&scene.render_args("out")));
    assert!(render.status.success(), "{}", stderr(&render));
    assert!(!has_bar(&stderr(&render)), "{:?}", stderr(&render));

    let photo = scene.gallery();
    let board = tiny_board();
    let convert = run(&["convert", &photo, "--board", &board]);
    assert!(convert.status.success(), "{}", stderr(&convert));
    assert!(!has_bar(&stderr(&convert)), "{:?}", stderr(&convert));
    assert!(
        stderr(&convert).contains("1 converted"),
        "{}",
        stderr(&convert)
    );
}

/// A bar on a terminal: its counter, and the escape sequence that clears its line (a
/// terminal turns every newline into a carriage return and a newline, so those say
/// nothing here).
fn drew(text: &str, counter: &str) -> bool {
    text.contains(counter) || text.contains("\x1b[2K")
}

#[test]
fn a_terminal_gets_a_bar_unless_json_or_verbose() {
    let scene = Scene::new();
    let Some(shown) = on_terminal(&strs(&scene.render_args("out"))) else {
        return;
    };
    assert!(
        shown.contains("/6 views") && shown.contains("\x1b[2K"),
        "{shown:?}"
    );

    let mut verbose = scene.render_args("out-v");
    verbose.push("-v".into());
    let logged = on_terminal(&strs(&verbose)).unwrap();
    assert!(!drew(&logged, "/6 views"), "{logged:?}");

    let photo = scene.gallery();
    let board = tiny_board();
    let shown = on_terminal(&["convert", &photo, "--board", &board, "--force"]).unwrap();
    assert!(drew(&shown, "/1 photos"), "{shown:?}");
    let json = on_terminal(&["convert", &photo, "--board", &board, "--force", "--json"]).unwrap();
    assert!(!drew(&json, "/1 photos"), "{json:?}");
    let line = json
        .lines()
        .find(|l| l.starts_with('{'))
        .expect("a JSON line");
    serde_json::from_str::<serde_json::Value>(line.trim_end_matches('\r')).expect("clean JSON");
}
