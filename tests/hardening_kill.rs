//! Kill loop: `reshader render` and `reshader convert` are SIGKILLed at pseudo-random
//! moments (fixed seed, bounded count) while they replace the output of an earlier run
//! on another photo. After every kill the output folder may hold only complete files of
//! the old or the new run, besides at most a hidden temporary of the killed process (a
//! SIGKILL between writing and renaming one cannot be prevented); and once the next
//! run's start-up recovery has finished or discarded the killed run's commit and
//! deleted its temporaries, exactly the old or the new output.
//! Nothing here is timed: the delays only spread the kills over the run.

use crate::spine_support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use spine_support::*;

const KILLS: usize = 12;
const MARKER: &str = ".reshader-done.json";

/// Relative path → bytes of every file below `dir`.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for entry in entries.map(Result::unwrap) {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let rel = path.strip_prefix(dir).unwrap().display().to_string();
                files.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

/// The photo a run.json or done-marker describes, by the sha256 it records.
fn recorded_sha(json: &[u8], what: &str) -> String {
    let value: serde_json::Value =
        serde_json::from_slice(json).unwrap_or_else(|e| panic!("{what} is not complete JSON: {e}"));
    let sha = value
        .get("sha256")
        .or_else(|| value.pointer("/inputs/photo/sha256"))
        .and_then(|s| s.as_str())
        .unwrap_or_else(|| panic!("{what} records no photo sha256: {value}"));
    sha.to_owned()
}

/// One run's complete output: files (run.json and the marker compared by the photo they
/// record, since they hold timings) and the photo's sha256.
struct Reference {
    sha: String,
    files: BTreeMap<String, Vec<u8>>,
}

impl Reference {
    fn holds(&self, rel: &str, bytes: &[u8]) -> bool {
        if rel.ends_with("run.json") || rel.ends_with(MARKER) {
            return self.files.contains_key(rel) && recorded_sha(bytes, rel) == self.sha;
        }
        self.files.get(rel).is_some_and(|b| b == bytes)
    }

    /// Whether `state` is this run's output (a convert interrupted before its marker was
    /// rewritten counts as complete when every output file is there).
    fn is_complete(&self, state: &BTreeMap<String, Vec<u8>>) -> bool {
        let needed = self.files.keys().filter(|rel| !rel.ends_with(MARKER));
        needed.clone().all(|rel| state.contains_key(rel))
            && state.len() <= needed.count() + 1
            && state.iter().all(|(rel, bytes)| self.holds(rel, bytes))
    }
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Deterministic pseudo-random fractions in [0, 1) (64-bit LCG).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

struct Setup {
    work: PathBuf,
    photos: [Vec<u8>; 2],
    depth: String,
}

impl Setup {
    fn new(root: &Path) -> Self {
        let (photo, depth) = write_scene(root);
        let a = std::fs::read(&photo).unwrap();
        let mut inverted = scene_photo();
        inverted
            .pixels_mut()
            .for_each(|p| p.0 = p.0.map(|v| 255 - v));
        let mut b = Vec::new();
        inverted
            .write_to(&mut std::io::Cursor::new(&mut b), image::ImageFormat::Png)
            .unwrap();
        let work = root.join("work");
        std::fs::create_dir_all(&work).unwrap();
        std::fs::copy(&depth, work.join("photo_depth.npy")).unwrap();
        Self {
            work,
            photos: [a, b],
            depth,
        }
    }

    /// Puts photo `which` at work/photo.png (atomically: the previous run may still
    /// have been reading it when it was killed).
    fn place(&self, which: usize) -> String {
        let path = self.work.join("photo.png");
        let tmp = self.work.join("photo.png.part");
        std::fs::write(&tmp, &self.photos[which]).unwrap();
        std::fs::rename(&tmp, &path).unwrap();
        path.display().to_string()
    }

    fn command(&self, convert: bool, out: &Path) -> Command {
        let board = tiny_board();
        let photo = self.work.join("photo.png").display().to_string();
        let out = out.display().to_string();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_reshader"));
        // Reshading off: the timings and outputs must not depend on a shipped model.
        cmd.env("RESHADER_MODEL", "none");
        if convert {
            cmd.args(["convert", &photo, "--board", &board, "--out", &out]);
        } else {
            cmd.args(["render", &photo, "--depth", &self.depth, "--board", &board]);
            cmd.args(["--out", &out]);
        }
        cmd.stdout(Stdio::null()).stderr(Stdio::piped());
        cmd
    }

    /// Runs to the end into a fresh folder; returns the output and how long it took.
    fn reference(&self, convert: bool, which: usize, out: &Path) -> (Reference, Duration) {
        self.place(which);
        let started = Instant::now();
        let output = self.command(convert, out).output().unwrap();
        let took = started.elapsed();
        assert!(output.status.success(), "{}", stderr(&output));
        // convert keeps each photo's outputs in OUT/<photo name>/.
        let files = snapshot(&if convert {
            out.join("photo")
        } else {
            out.into()
        });
        let reference = Reference {
            sha: sha256_hex(&self.photos[which]),
            files,
        };
        (reference, took)
    }
}

/// After a kill: only complete files, each one of the old or the new run's, and no
/// temporaries among them but the killed process's own (`.<name>.tmp-<pid>`).
fn check_after_kill(
    state: &BTreeMap<String, Vec<u8>>,
    refs: &[Reference; 2],
    killed: u32,
    at: &str,
) {
    let own_temporary = format!(".tmp-{killed}");
    for (rel, bytes) in state {
        let name = Path::new(rel).file_name().unwrap().to_string_lossy();
        if name.starts_with('.') && name.ends_with(&own_temporary) {
            continue;
        }
        assert!(
            !name.starts_with('.') || name == MARKER,
            "{at}: temporary {rel} in the output folder"
        );
        assert!(
            refs.iter().any(|r| r.holds(rel, bytes)),
            "{at}: {rel} ({} bytes) is neither the old nor the new run's",
            bytes.len()
        );
    }
}

fn kill_loop(convert: bool) {
    let dir = tempfile::tempdir().unwrap();
    let setup = Setup::new(dir.path());
    let mut refs = Vec::new();
    let mut longest = Duration::ZERO;
    for which in 0..2 {
        let (r, took) = setup.reference(convert, which, &dir.path().join(format!("ref{which}")));
        refs.push(r);
        longest = longest.max(took);
    }
    let refs: [Reference; 2] = refs.try_into().ok().unwrap();
    let out_root = dir.path().join("out");
    let out = if convert {
        out_root.join("photo")
    } else {
        out_root.clone()
    };
    let mut rng = Lcg(if convert { 11 } else { 7 });
    let mut finished_kills = 0;
    for i in 0..KILLS {
        let which = i % 2;
        setup.place(which);
        let mut child = setup.command(convert, &out_root).spawn().unwrap();
        let killed = child.id();
        // Spread over the whole run, half the kills in its last third (the commit).
        let fraction = if i % 2 == 0 {
            rng.next()
        } else {
            0.66 + 0.4 * rng.next()
        };
        std::thread::sleep(longest.mul_f64(fraction));
        let _ = child.kill();
        let status = child.wait().unwrap();
        finished_kills += usize::from(status.success());
        let at = format!("kill {i} after {fraction:.2} of a run");
        check_after_kill(&snapshot(&out), &refs, killed, &at);
        // What the next run does first; then the folder is one run's whole output.
        reshader::io::output::recover(&out).unwrap();
        let state = snapshot(&out);
        assert!(
            state.is_empty() || refs.iter().any(|r| r.is_complete(&state)),
            "{at}: after recovery the folder is neither run's whole output: {:?}",
            state.keys().collect::<Vec<_>>()
        );
    }
    // Kills that came after the run ended test nothing; say how many there were.
    eprintln!("{finished_kills} of {KILLS} runs had finished before their kill");
    // A last run to the end leaves the new output and nothing else beside it.
    setup.place(1);
    let output = setup.command(convert, &out_root).output().unwrap();
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(refs[1].is_complete(&snapshot(&out)));
    let leftovers: Vec<String> = entries(&out_root)
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(
        leftovers.is_empty(),
        "left beside the output: {leftovers:?}"
    );
}

#[test]
fn killed_render_leaves_old_or_new_output() {
    kill_loop(false);
}

#[test]
fn killed_convert_leaves_old_or_new_output() {
    kill_loop(true);
}
