//! Gallery hooks end to end through the binary: `convert` on a batch with corrupt photos,
//! on photos without depth sidecars, and `watch` with photos appearing while it runs,
//! stopped by SIGTERM and restarted.

use crate::depth_support;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::Duration;

use image::{Rgb, RgbImage};
use serde_json::Value;

/// Upper bound on waiting for the watcher; only a hang reaches it.
const PATIENCE: Duration = Duration::from_secs(120);

const TINY_BOARD: &str = r#"
name = "tiny-4view"
description = "4-view slanted lenticular, 48x32, for tests"
width = 48
height = 32
views = 4
quilt_cols = 2
quilt_rows = 2
view_width = 24
view_height = 16
view_cone_deg = 20.0
subpixels = "rgb"

[van_berkel]
slant_deg = 18.434948822922010
lens_pitch = 4.0
offset = 0.5
"#;

/// The binary with reshading off unless a test passes --model, so these tests neither
/// slow down nor change when a trained model ships in models/reshade.
fn reshader() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_reshader"));
    cmd.env("RESHADER_MODEL", "none");
    cmd
}

fn board(dir: &Path) -> PathBuf {
    let path = dir.join("tiny.toml");
    std::fs::write(&path, TINY_BOARD).unwrap();
    path
}

fn photo_bytes(seed: u32) -> Vec<u8> {
    let image = RgbImage::from_fn(32, 24, |x, y| {
        Rgb([(x * 8 + seed * 11) as u8, (y * 10) as u8, (seed * 37) as u8])
    });
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    bytes
}

/// A depth sidecar: a left-to-right ramp from 1 to 3 units.
fn write_depth(photo: &Path) {
    let (w, h) = (32usize, 24usize);
    let data: Vec<f32> = (0..w * h)
        .map(|i| 1.0 + 2.0 * (i % w) as f32 / w as f32)
        .collect();
    let stem = photo.file_stem().unwrap().to_string_lossy();
    let path = photo.with_file_name(format!("{stem}_depth.npy"));
    std::fs::write(path, reshader::io::npy::encode_f32(&[h, w], &data)).unwrap();
}

/// The small fixture depth network (fast to load and run).
fn fixture_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/depth/fixture-logdisp.json")
}

fn json_lines(stdout: &[u8]) -> Vec<Value> {
    String::from_utf8_lossy(stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON: {l}: {e}")))
        .collect()
}

fn status_of(lines: &[Value], status: &str) -> usize {
    lines.iter().filter(|l| l["status"] == status).count()
}

/// Files whose names say they are temporaries or staging areas, anywhere under `dir`.
fn leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.contains(".tmp-") || name.contains(".staging-") {
            found.push(path.clone());
        }
        if path.is_dir() {
            found.extend(leftovers(&path));
        }
    }
    found
}

#[test]
fn batch_of_20_with_2_corrupt_converts_18_and_reports_2() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photos_dir = dir.path().join("photos");
    std::fs::create_dir(&photos_dir).unwrap();
    let mut photos = Vec::new();
    for i in 0..20u32 {
        let path = photos_dir.join(format!("photo_{i:02}.jpg"));
        let bytes = match i {
            7 => photo_bytes(i)[..200].to_vec(), // truncated JPEG
            13 => Vec::new(),                    // zero-length file
            _ => photo_bytes(i),
        };
        std::fs::write(&path, bytes).unwrap();
        write_depth(&path);
        photos.push(path);
    }
    let out = dir.path().join("out");
    let run = |extra: &[&str]| {
        let output = reshader()
            .arg("convert")
            .args(&photos)
            .arg("--board")
            .arg(&board)
            .arg("--out")
            .arg(&out)
            .arg("--json")
            .args(extra)
            .output()
            .unwrap();
        (output.status, json_lines(&output.stdout), output.stderr)
    };

    let (status, lines, stderr) = run(&[]);
    let stderr = String::from_utf8_lossy(&stderr);
    assert!(
        !status.success(),
        "a batch with failures must exit non-zero"
    );
    assert!(stderr.contains("2 of 20 photos failed"), "{stderr}");
    assert_eq!(lines.len(), 20);
    assert_eq!(status_of(&lines, "converted"), 18);
    for (i, line) in lines.iter().enumerate() {
        assert_eq!(line["photo"], photos[i].to_str().unwrap(), "order kept");
        if i == 7 || i == 13 {
            assert_eq!(line["status"], "failed");
            let error = line["error"].as_str().unwrap();
            assert!(error.contains(&format!("photo_{i:02}.jpg")), "{error}");
            continue;
        }
        let panel = out.join(format!("photo_{i:02}/panel.png"));
        let outputs: Vec<&str> = line["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o.as_str().unwrap())
            .collect();
        assert!(outputs.contains(&panel.to_str().unwrap()), "{outputs:?}");
        assert_eq!(
            image::open(&panel).unwrap().to_rgb8().dimensions(),
            (48, 32)
        );
        assert!(line["timings_ms"]["total"].as_f64().unwrap() > 0.0);
        assert!(line["error"].is_null());
    }
    assert!(!out.join("photo_07").join("panel.png").exists());
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));

    let (_, again, _) = run(&[]);
    assert_eq!(
        status_of(&again, "skipped"),
        18,
        "finished photos are not redone"
    );
    assert_eq!(status_of(&again, "failed"), 2);

    let (_, forced, _) = run(&["--force"]);
    assert_eq!(status_of(&forced, "converted"), 18);
}

#[test]
fn convert_succeeds_with_exit_0_and_human_output() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photo = dir.path().join("one.jpg");
    std::fs::write(&photo, photo_bytes(1)).unwrap();
    write_depth(&photo);
    let output = reshader()
        .args([
            "convert",
            photo.to_str().unwrap(),
            "--board",
            board.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.starts_with("converted "), "{stdout}");
    assert!(dir.path().join("one.reshader/panel.png").is_file());
    assert!(dir.path().join("one.reshader/run.json").is_file());
}

#[test]
fn convert_without_sidecars_uses_embedded_depth_or_the_network_loaded_once() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photos = dir.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    let plain = [photos.join("plain1.jpg"), photos.join("plain2.jpg")];
    for (i, p) in plain.iter().enumerate() {
        std::fs::write(p, photo_bytes(i as u32)).unwrap();
    }
    let portrait = photos.join("portrait.jpg");
    let (png, _) = depth_support::depth_png(20, 15);
    let gdepth = depth_support::gdepth_jpeg(&depth_support::base64(&png), "RangeInverse", 900);
    std::fs::write(&portrait, gdepth).unwrap();
    let side = photos.join("side.jpg");
    std::fs::write(&side, photo_bytes(9)).unwrap();
    write_depth(&side);

    let output = reshader()
        .args(["-v", "convert"])
        .args([&plain[0], &plain[1], &portrait, &side])
        .arg("--board")
        .arg(&board)
        .arg("--depth-model")
        .arg(fixture_model())
        .arg("--json")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let lines = json_lines(&output.stdout);
    assert_eq!(status_of(&lines, "converted"), 4, "{lines:?}");
    assert_eq!(
        stderr.matches("fixture-logdisp.onnx loaded in").count(),
        1,
        "the depth network is loaded once per process: {stderr}"
    );
    let source = |photo: &Path| {
        let stem = photo.file_stem().unwrap().to_string_lossy();
        let run = std::fs::read(photo.with_file_name(format!("{stem}.reshader/run.json")));
        let run: Value = serde_json::from_slice(&run.unwrap()).unwrap();
        run["inputs"]["depth"]["source"]
            .as_str()
            .unwrap()
            .to_string()
    };
    assert_eq!(source(&plain[0]), "network");
    assert_eq!(source(&plain[1]), "network");
    assert_eq!(source(&portrait), "embedded");
    assert_eq!(source(&side), "file");
    for line in &lines[..2] {
        assert!(line["timings_ms"]["depth"].as_f64().is_some(), "{line}");
    }
}

#[test]
fn convert_with_a_missing_depth_model_fails_before_any_photo() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photo = dir.path().join("one.jpg");
    std::fs::write(&photo, photo_bytes(1)).unwrap();
    let output = reshader()
        .arg("convert")
        .arg(&photo)
        .arg("--board")
        .arg(&board)
        .args(["--depth-model", "no-such-model.onnx", "--json"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("error: ") && stderr.contains("no-such-model.onnx"),
        "{stderr}"
    );
    assert!(output.stdout.is_empty(), "no photo was attempted");
    assert!(!dir.path().join("one.reshader").exists());
}

/// The tiny reshading fixture network.
fn fixture_reshade_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures/reshade-fixture-fp32.json")
}

#[test]
fn convert_reshades_with_the_model_loaded_once_and_records_it() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photos = [dir.path().join("a.jpg"), dir.path().join("b.jpg")];
    for (i, p) in photos.iter().enumerate() {
        std::fs::write(p, photo_bytes(i as u32 + 3)).unwrap();
        write_depth(p);
    }
    let out = dir.path().join("out");
    let convert = |model: &Path| {
        reshader()
            .args(["-v", "convert"])
            .args(&photos)
            .arg("--board")
            .arg(&board)
            .arg("--out")
            .arg(&out)
            .arg("--model")
            .arg(model)
            .arg("--json")
            .output()
            .unwrap()
    };
    let output = convert(&fixture_reshade_model());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let lines = json_lines(&output.stdout);
    assert_eq!(status_of(&lines, "converted"), 2, "{lines:?}");
    assert_eq!(
        stderr
            .matches("reshading with reshade-fixture-fp32")
            .count(),
        1,
        "the reshading network is loaded once per process: {stderr}"
    );
    for name in ["a", "b"] {
        let run: Value =
            serde_json::from_slice(&std::fs::read(out.join(name).join("run.json")).unwrap())
                .unwrap();
        let reshade = run["reshade"].as_str().unwrap();
        assert!(
            reshade.starts_with("reshade-fixture-fp32 ") && reshade.contains("fp32"),
            "{run}"
        );
    }

    // Another model is another conversion: the done-markers must not skip the photos.
    let none = convert(Path::new("none"));
    assert!(none.status.success());
    let lines = json_lines(&none.stdout);
    assert_eq!(status_of(&lines, "converted"), 2, "{lines:?}");
    let run: Value =
        serde_json::from_slice(&std::fs::read(out.join("a/run.json")).unwrap()).unwrap();
    assert_eq!(run["reshade"], "identity (no model)");
    let again = convert(Path::new("none"));
    assert_eq!(status_of(&json_lines(&again.stdout), "skipped"), 2);
}

#[test]
fn convert_with_a_bad_reshading_model_fails_before_any_photo() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photo = dir.path().join("one.jpg");
    std::fs::write(&photo, photo_bytes(1)).unwrap();
    write_depth(&photo);
    let broken = dir.path().join("broken-reshade.json");
    std::fs::write(&broken, b"{\"format\": ").unwrap();
    for model in [broken, dir.path().join("missing-reshade.json")] {
        let output = reshader()
            .arg("convert")
            .arg(&photo)
            .arg("--board")
            .arg(&board)
            .arg("--model")
            .arg(&model)
            .arg("--json")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        let name = model.file_name().unwrap().to_string_lossy();
        assert!(
            stderr.contains("error: ") && stderr.contains(&*name),
            "{stderr}"
        );
        assert!(output.stdout.is_empty(), "no photo was attempted");
        assert!(!dir.path().join("one.reshader").exists());
    }
}

/// Lines of a child's stdout, read on a thread so waits can be bounded.
fn line_reader(child: &mut Child) -> Receiver<String> {
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// The next report, as (photo file name, status).
fn next_report(lines: &Receiver<String>) -> (String, String) {
    let line = lines
        .recv_timeout(PATIENCE)
        .expect("watch reported nothing in time");
    let v: Value = serde_json::from_str(&line).unwrap();
    let photo = Path::new(v["photo"].as_str().unwrap())
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    (photo, v["status"].as_str().unwrap().to_string())
}

fn spawn_watch(dir: &Path, board: &Path, out: &Path, extra: &[&str]) -> Child {
    reshader()
        .arg("watch")
        .arg(dir)
        .arg("--board")
        .arg(board)
        .arg("--out")
        .arg(out)
        .args(["--json", "--settle-ms", "300", "--rescan-ms", "200"])
        .arg("--depth-model")
        .arg(fixture_model())
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Sends SIGTERM and waits (bounded) for a clean exit.
fn terminate(mut child: Child) -> String {
    // SAFETY: kill(2) on the pid of a child this test spawned and has not reaped.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
    }
    for _ in 0..(PATIENCE.as_millis() / 50) {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
            assert!(status.success(), "watch exited with {status}: {stderr}");
            return stderr;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.kill().unwrap();
    panic!("watch did not stop on SIGTERM");
}

#[test]
fn watch_converts_photos_as_they_appear_and_survives_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let inbox = dir.path().join("inbox");
    let out = dir.path().join("out");
    std::fs::create_dir(&inbox).unwrap();

    // Already there when the watcher starts.
    let a = inbox.join("a.jpg");
    write_depth(&a);
    std::fs::write(&a, photo_bytes(1)).unwrap();

    let mut child = spawn_watch(&inbox, &board, &out, &[]);
    let lines = line_reader(&mut child);
    assert_eq!(next_report(&lines), ("a.jpg".into(), "converted".into()));

    // Saved the way camera apps do: a hidden temporary renamed into place; no depth
    // sidecar, so the depth network estimates it.
    let b = inbox.join("b.jpg");
    let tmp = inbox.join(".b.jpg.partial");
    std::fs::write(&tmp, photo_bytes(2)).unwrap();
    std::fs::rename(&tmp, &b).unwrap();
    assert_eq!(next_report(&lines), ("b.jpg".into(), "converted".into()));

    // A slow writer that pauses longer than the settle time with the file open: the
    // watcher must wait for the close, or it would convert half a JPEG and fail.
    let c = inbox.join("c.jpg");
    write_depth(&c);
    let bytes = photo_bytes(3);
    let mut file = std::fs::File::create(&c).unwrap();
    file.write_all(&bytes[..bytes.len() / 2]).unwrap();
    file.flush().unwrap();
    std::thread::sleep(Duration::from_millis(1000));
    file.write_all(&bytes[bytes.len() / 2..]).unwrap();
    drop(file);
    assert_eq!(next_report(&lines), ("c.jpg".into(), "converted".into()));

    // A writer that closes the file half-written and comes back later to finish it (a
    // sync tool writing in pieces): the closed half is cut off before its end-of-image
    // marker, so the watcher waits for the rest instead of converting (or failing) it.
    let f = inbox.join("f.jpg");
    write_depth(&f);
    let bytes = photo_bytes(6);
    std::fs::write(&f, &bytes[..bytes.len() / 2]).unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let mut file = std::fs::OpenOptions::new().append(true).open(&f).unwrap();
    file.write_all(&bytes[bytes.len() / 2..]).unwrap();
    drop(file);
    assert_eq!(next_report(&lines), ("f.jpg".into(), "converted".into()));

    // A corrupt photo fails alone; the watcher carries on with the next.
    let d = inbox.join("d.jpg");
    write_depth(&d);
    std::fs::write(&d, b"definitely not a jpeg").unwrap();
    assert_eq!(next_report(&lines), ("d.jpg".into(), "failed".into()));
    let e = inbox.join("e.png");
    write_depth(&e);
    image::load_from_memory(&photo_bytes(5))
        .unwrap()
        .save(inbox.join(".e.tmp.png"))
        .unwrap();
    std::fs::rename(inbox.join(".e.tmp.png"), &e).unwrap();
    assert_eq!(next_report(&lines), ("e.png".into(), "converted".into()));

    let stderr = terminate(child);
    assert!(
        stderr.contains("stopped: 5 converted, 0 skipped, 1 failed"),
        "{stderr}"
    );
    for name in ["a", "b", "c", "e", "f"] {
        assert!(out.join(name).join("panel.png").is_file(), "{name}");
    }
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));

    // Restarted (polling this time): finished photos are skipped, not redone.
    let mut child = spawn_watch(&inbox, &board, &out, &["--poll"]);
    let lines = line_reader(&mut child);
    let mut seen: Vec<(String, String)> = (0..6).map(|_| next_report(&lines)).collect();
    seen.sort();
    let expect = |n: &str, s: &str| (n.to_string(), s.to_string());
    assert_eq!(
        seen,
        [
            expect("a.jpg", "skipped"),
            expect("b.jpg", "skipped"),
            expect("c.jpg", "skipped"),
            expect("d.jpg", "failed"),
            expect("e.png", "skipped"),
            expect("f.jpg", "skipped"),
        ]
    );
    let stderr = terminate(child);
    assert!(
        stderr.contains("stopped: 0 converted, 5 skipped, 1 failed"),
        "{stderr}"
    );
}

#[test]
fn watch_with_a_bad_reshading_model_fails_before_reading_the_folder() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photos = dir.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    let photo = photos.join("there.jpg");
    std::fs::write(&photo, photo_bytes(2)).unwrap();
    write_depth(&photo);
    let out = dir.path().join("out");
    let mut child = spawn_watch(&photos, &board, &out, &["--model", "no-such-reshade.json"]);
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        assert!(started.elapsed() < PATIENCE, "watch kept running");
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no-such-reshade.json"), "{stderr}");
    assert!(output.stdout.is_empty(), "no photo was attempted");
    assert!(!out.exists());
}

/// Issue 26: the already-converted check ignored the depth sidecar, so a corrected
/// depth map never reached the gallery.
#[test]
fn convert_again_when_the_depth_sidecar_changes() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photo = dir.path().join("one.jpg");
    std::fs::write(&photo, photo_bytes(4)).unwrap();
    write_depth(&photo);
    let convert = || {
        let output = reshader()
            .args(["convert", photo.to_str().unwrap(), "--json", "--board"])
            .arg(&board)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        json_lines(&output.stdout)[0]["status"]
            .as_str()
            .unwrap()
            .to_string()
    };
    assert_eq!(convert(), "converted");
    assert_eq!(convert(), "skipped");
    // A right-to-left ramp instead.
    let (w, h) = (32usize, 24usize);
    let data: Vec<f32> = (0..w * h)
        .map(|i| 3.0 - 2.0 * (i % w) as f32 / w as f32)
        .collect();
    std::fs::write(
        dir.path().join("one_depth.npy"),
        reshader::io::npy::encode_f32(&[h, w], &data),
    )
    .unwrap();
    assert_eq!(convert(), "converted");
    assert_eq!(convert(), "skipped");
}

/// Issue 26: `convert DIR/*` counted its own sidecars and NAME.reshader/ folders as
/// failed photos and exited 1 when run again; `convert DIR` said "Is a directory"; a
/// FIFO among the inputs hung the batch.
#[test]
fn convert_takes_folders_and_globs_and_passes_over_what_is_not_a_photo() {
    let dir = tempfile::tempdir().unwrap();
    let board = board(dir.path());
    let photos = dir.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    for (name, seed) in [("a.jpg", 1), ("b.JPG", 2)] {
        let photo = photos.join(name);
        std::fs::write(&photo, photo_bytes(seed)).unwrap();
        write_depth(&photo);
    }
    std::fs::write(photos.join("notes.txt"), b"not a photo").unwrap();
    let fifo = photos.join("pipe.jpg");
    let c_path = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: mkfifo(3) on a NUL-terminated path inside the test's own directory.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o644) }, 0);
    let glob = || -> Vec<PathBuf> {
        let mut all: Vec<PathBuf> = std::fs::read_dir(&photos)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        all.sort();
        all
    };
    let convert = |inputs: &[PathBuf]| {
        let mut child = reshader()
            .args(["-v", "convert", "--json", "--board"])
            .arg(&board)
            .args(inputs)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let started = std::time::Instant::now();
        while child.try_wait().unwrap().is_none() {
            assert!(started.elapsed() < PATIENCE, "convert hung");
            std::thread::sleep(Duration::from_millis(50));
        }
        child.wait_with_output().unwrap()
    };
    // The shell's DIR/*: photos, sidecars, a text file and a FIFO.
    let first = convert(&glob());
    let stderr = String::from_utf8_lossy(&first.stderr);
    assert_eq!(first.status.code(), Some(0), "{stderr}");
    let lines = json_lines(&first.stdout);
    assert_eq!(status_of(&lines, "converted"), 2, "{lines:?}");
    assert_eq!(lines.len(), 2, "{lines:?}");
    assert!(stderr.contains("pipe.jpg: it is a FIFO"), "{stderr}");
    assert!(
        stderr.contains("a_depth.npy: the depth sidecar of"),
        "{stderr}"
    );
    assert!(stderr.contains("notes.txt: not a JPEG or PNG"), "{stderr}");
    // Again over DIR/*, which now also holds a.reshader/ and b.reshader/; and over DIR.
    for inputs in [glob(), vec![photos.clone()]] {
        let again = convert(&inputs);
        let stderr = String::from_utf8_lossy(&again.stderr);
        assert_eq!(again.status.code(), Some(0), "{stderr}");
        let lines = json_lines(&again.stdout);
        assert_eq!(
            (lines.len(), status_of(&lines, "skipped")),
            (2, 2),
            "{lines:?}"
        );
    }
    let again = convert(&glob());
    assert!(String::from_utf8_lossy(&again.stderr).contains("a.reshader: a reshader output folder"));
    // Nothing but things that are not photos: an error, not a silent success.
    let none = convert(&[photos.join("notes.txt"), fifo.clone()]);
    assert_eq!(none.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&none.stderr).contains("none of the inputs is a photo"));
    // render never opens a FIFO either.
    let render = reshader()
        .args(["render"])
        .arg(&fifo)
        .arg("--board")
        .arg(&board)
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&render.stderr);
    assert_eq!(render.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("pipe.jpg") && stderr.contains("FIFO"),
        "{stderr}"
    );
}
