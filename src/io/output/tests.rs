//! Unit tests of `io::output`, beside it so that the module file holds the code only.

use super::*;

#[test]
fn atomic_write_replaces_and_leaves_no_temp() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.txt");
    write_atomic(&path, b"one").unwrap();
    write_atomic(&path, b"two").unwrap();
    assert_eq!(fs::read(&path).unwrap(), b"two");
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn dropped_staging_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    {
        let mut staging = Staging::new(&out).unwrap();
        staging.write("views/view_00.png", b"x").unwrap();
    }
    assert!(!out.exists());
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn commit_moves_files_and_drops_stale_views() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    fs::create_dir_all(out.join("views")).unwrap();
    fs::write(out.join("views/view_07.png"), b"old").unwrap();
    fs::write(out.join("views/notes.txt"), b"keep").unwrap();
    let mut staging = Staging::new(&out).unwrap();
    staging.write("views/view_00.png", b"new").unwrap();
    staging.write("run.json", b"{}").unwrap();
    let files = staging.commit().unwrap();
    assert_eq!(files.len(), 2);
    assert_eq!(fs::read(out.join("views/view_00.png")).unwrap(), b"new");
    assert!(!out.join("views/view_07.png").exists());
    assert!(out.join("views/notes.txt").exists());
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn commit_removes_what_the_previous_run_json_lists_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    fs::create_dir_all(out.join("views")).unwrap();
    let old = [
        "views/view_00.png",
        "quilt_qs8x6a0.75.png",
        "panel.png",
        "sbs.png",
        "run.json",
    ];
    for name in old {
        fs::write(out.join(name), b"old").unwrap();
    }
    fs::write(dir.path().join("outside.txt"), b"keep").unwrap();
    fs::write(out.join("notes.txt"), b"keep").unwrap();
    let mut listed: Vec<&str> = old.to_vec();
    listed.extend(["../outside.txt", "/etc/hostname", ""]);
    let record = serde_json::json!({ "outputs": listed });
    fs::write(out.join("run.json"), record.to_string()).unwrap();
    let mut staging = Staging::new(&out).unwrap();
    staging.write("panel.png", b"new").unwrap();
    staging.write("run.json", b"{}").unwrap();
    staging.commit().unwrap();
    let mut left: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["notes.txt", "panel.png", "run.json"]);
    assert_eq!(fs::read(out.join("panel.png")).unwrap(), b"new");
    assert!(dir.path().join("outside.txt").exists());
}

#[test]
fn an_abandoned_commit_also_finishes_its_removals() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    fs::create_dir_all(&out).unwrap();
    fs::write(out.join("sbs.png"), b"old").unwrap();
    fs::write(out.join("run.json"), b"new, moved in before the kill").unwrap();
    let stage = dir
        .path()
        .join(format!("{}{}", staging_prefix(&out), i32::MAX));
    fs::create_dir_all(&stage).unwrap();
    fs::write(stage.join("panel.png"), b"new").unwrap();
    fs::write(stage.join(COMMIT_LIST), "panel.png\nrun.json\n-sbs.png\n").unwrap();
    drop(Staging::new(&out).unwrap());
    assert_eq!(fs::read(out.join("panel.png")).unwrap(), b"new");
    assert!(!out.join("sbs.png").exists());
}

/// A staging directory as a run killed during its commit leaves it.
fn abandoned_commit(dir: &Path, out: &Path, with_list: bool) {
    let stage = dir.join(format!("{}{}", staging_prefix(out), i32::MAX));
    fs::create_dir_all(stage.join("views")).unwrap();
    fs::write(stage.join("views/view_00.png"), b"new0").unwrap();
    fs::write(stage.join("run.json"), b"new").unwrap();
    if with_list {
        // view_01 had been moved in already when the run died.
        fs::write(out.join("views/view_01.png"), b"new1").unwrap();
        let list = "views/view_00.png\nviews/view_01.png\nrun.json\n";
        fs::write(stage.join(COMMIT_LIST), list).unwrap();
    }
}

#[test]
fn next_run_finishes_or_discards_an_abandoned_commit() {
    for with_list in [true, false] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        fs::create_dir_all(out.join("views")).unwrap();
        for (name, bytes) in [("views/view_00.png", "old0"), ("views/view_01.png", "old1")] {
            fs::write(out.join(name), bytes).unwrap();
        }
        fs::write(out.join("views/view_02.png"), b"old2").unwrap();
        fs::write(out.join("run.json"), b"old").unwrap();
        fs::write(out.join(format!(".run.json.tmp-{}", i32::MAX)), b"ne").unwrap();
        abandoned_commit(dir.path(), &out, with_list);
        drop(Staging::new(&out).unwrap());
        let read = |name: &str| fs::read_to_string(out.join(name)).ok();
        if with_list {
            assert_eq!(read("views/view_00.png").as_deref(), Some("new0"));
            assert_eq!(read("views/view_01.png").as_deref(), Some("new1"));
            assert_eq!(read("views/view_02.png"), None, "stale view kept");
            assert_eq!(read("run.json").as_deref(), Some("new"));
        } else {
            assert_eq!(read("views/view_00.png").as_deref(), Some("old0"));
            assert_eq!(read("views/view_02.png").as_deref(), Some("old2"));
            assert_eq!(read("run.json").as_deref(), Some("old"));
        }
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1, "staging left");
        assert_eq!(fs::read_dir(&out).unwrap().count(), 2, "temporary left");
    }
}

#[test]
fn view_names_parse() {
    assert_eq!(view_index("view_07.png"), Some(7));
    assert_eq!(view_index("view_123.exr"), Some(123));
    assert_eq!(view_index("view_.png"), None);
    assert_eq!(view_index("view_01.png.bak"), None);
    assert_eq!(view_index("view_01.txt"), None);
}

#[test]
fn pngs_encoded_in_parallel_decode_to_their_images_in_order() {
    let images: Vec<RgbImage> = (0..5u8)
        .map(|i| {
            RgbImage::from_fn(7, 3, |x, y| {
                image::Rgb([i * 40, x as u8 * 30, y as u8 * 80])
            })
        })
        .collect();
    let jobs: Vec<(PathBuf, &RgbImage)> = images
        .iter()
        .enumerate()
        .map(|(i, image)| (PathBuf::from(format!("view_{i:02}.png")), image))
        .collect();
    let encoded = encode_pngs(&jobs).unwrap();
    assert_eq!(encoded.len(), images.len());
    for (bytes, image) in encoded.iter().zip(&images) {
        let decoded = image::load_from_memory(bytes).unwrap().to_rgb8();
        assert_eq!(&decoded, image);
    }
}

#[test]
fn recovery_removes_a_dead_runs_probe_beside_the_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("photo");
    // No process has this id: kill(2) takes ids up to the kernel's pid_max (2^22).
    let dead = dir.path().join(format!("{PROBE_PREFIX}{}", i32::MAX));
    let live = dir
        .path()
        .join(format!("{PROBE_PREFIX}{}", std::process::id()));
    let other = dir.path().join(".notes.tmp-2147483647");
    for f in [&dead, &live, &other] {
        fs::write(f, b"").unwrap();
    }
    recover(&out).unwrap();
    assert!(!dead.exists());
    assert!(live.exists(), "a running process's probe stays");
    assert!(
        other.exists(),
        "only our probes are touched beside the output"
    );
}
