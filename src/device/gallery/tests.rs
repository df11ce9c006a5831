//! Unit tests of `device::gallery`, beside it so that the module file holds the code only.

use std::cell::Cell;

use super::*;

/// Writes one output file whose contents are the photo's, failing on photos that
/// start with "bad".
fn fake_converter(calls: &Cell<usize>) -> impl Converter + '_ {
    FnConverter::new("fake v1", move |photo: &Path, out: &Path| {
        calls.set(calls.get() + 1);
        let bytes = std::fs::read(photo)?;
        if bytes.starts_with(b"bad") {
            return Err(format!("{}: not a photo", photo.display()).into());
        }
        if bytes.starts_with(b"panic") {
            panic!("decoder bug");
        }
        std::fs::create_dir_all(out)?;
        let panel = out.join("panel.png");
        std::fs::write(&panel, &bytes)?;
        Ok::<_, ConvertError>(ConvertReport {
            outputs: vec![panel],
            timings_ms: BTreeMap::from([("render".into(), 1.0)]),
        })
    })
}

#[test]
fn converts_skips_and_isolates_failures() {
    let dir = tempfile::tempdir().unwrap();
    let photos: Vec<PathBuf> = ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]
        .iter()
        .map(|n| dir.path().join(n))
        .collect();
    std::fs::write(&photos[0], b"good a").unwrap();
    std::fs::write(&photos[1], b"bad b").unwrap();
    std::fs::write(&photos[2], b"panic c").unwrap();
    let calls = Cell::new(0);
    let conv = fake_converter(&calls);
    let mut reports = Vec::new();
    let summary = convert_batch(&photos, &OutLayout::BesidePhoto, false, &conv, |r| {
        reports.push(r.clone())
    });
    assert_eq!((summary.converted, summary.failed), (1, 3));
    assert_eq!(
        reports[0].outputs,
        [dir.path().join("a.reshader/panel.png")]
    );
    assert!(reports[1].error.as_ref().unwrap().contains("not a photo"));
    assert!(reports[2].error.as_ref().unwrap().contains("decoder bug"));
    assert!(reports[3].error.as_ref().unwrap().contains("d.jpg"));
    assert!(reports[0].timings_ms.contains_key("render"));

    let again = convert_batch(&photos[..1], &OutLayout::BesidePhoto, false, &conv, |_| {});
    assert_eq!(again.skipped, 1);
    assert_eq!(calls.get(), 3, "a skipped photo is not converted again");
    convert_batch(&photos[..1], &OutLayout::BesidePhoto, true, &conv, |_| {});
    assert_eq!(calls.get(), 4, "--force converts again");
}

#[test]
fn edited_photo_or_missing_output_is_redone() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.png");
    std::fs::write(&photo, b"v1").unwrap();
    let calls = Cell::new(0);
    let conv = fake_converter(&calls);
    let out = OutLayout::Under(dir.path().join("out"));
    let run = |expected: Status| {
        let s = convert_batch(std::slice::from_ref(&photo), &out, false, &conv, |r| {
            assert_eq!(r.status, expected, "{r}")
        });
        assert!(s.all_ok());
    };
    run(Status::Converted);
    run(Status::Skipped);
    std::fs::write(&photo, b"v2").unwrap();
    run(Status::Converted);
    std::fs::remove_file(dir.path().join("out/p/panel.png")).unwrap();
    run(Status::Converted);
    assert_eq!(calls.get(), 3);
}

#[test]
fn an_edited_added_or_removed_sidecar_converts_again() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.jpg");
    std::fs::write(&photo, b"good").unwrap();
    let calls = Cell::new(0);
    let conv = FnConverter::new("fake", |photo: &Path, out: &Path| {
        calls.set(calls.get() + 1);
        fake_converter(&Cell::new(0)).convert(photo, out)
    })
    .with_inputs(|photo| {
        let sidecar = photo.with_file_name("p_depth.npy");
        sidecar.is_file().then_some(sidecar).into_iter().collect()
    });
    let run = |expected: Status| {
        convert_batch(
            std::slice::from_ref(&photo),
            &OutLayout::BesidePhoto,
            false,
            &conv,
            |r| assert_eq!(r.status, expected, "{r}"),
        );
    };
    run(Status::Converted);
    run(Status::Skipped);
    let sidecar = dir.path().join("p_depth.npy");
    std::fs::write(&sidecar, b"depth v1").unwrap();
    run(Status::Converted);
    run(Status::Skipped);
    std::fs::write(&sidecar, b"depth v2").unwrap();
    run(Status::Converted);
    std::fs::remove_file(&sidecar).unwrap();
    run(Status::Converted);
    run(Status::Skipped);
    assert_eq!(calls.get(), 4);
}

#[test]
fn photos_sharing_an_output_directory_fail_alone() {
    let dir = tempfile::tempdir().unwrap();
    let photos = [dir.path().join("x.jpg"), dir.path().join("x.png")];
    for p in &photos {
        std::fs::write(p, b"good").unwrap();
    }
    let calls = Cell::new(0);
    let conv = fake_converter(&calls);
    let mut errors = Vec::new();
    convert_batch(&photos, &OutLayout::BesidePhoto, false, &conv, |r| {
        errors.push(r.error.clone())
    });
    assert!(errors[0].is_none());
    assert!(errors[1].as_ref().unwrap().contains("already used by"));
    // A later run with only the second photo must not take over the first's outputs.
    let later = convert_batch(&photos[1..], &OutLayout::BesidePhoto, false, &conv, |r| {
        assert!(
            r.error.as_ref().unwrap().contains("another photo, x.jpg"),
            "{r}"
        )
    });
    assert_eq!(later.failed, 1);
}

#[test]
fn failed_conversion_leaves_no_done_marker() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.jpg");
    std::fs::write(&photo, b"good").unwrap();
    let calls = Cell::new(0);
    let conv = fake_converter(&calls);
    convert_batch(
        std::slice::from_ref(&photo),
        &OutLayout::BesidePhoto,
        false,
        &conv,
        |_| {},
    );
    let marker = dir.path().join("p.reshader").join(DONE_MARKER);
    assert!(marker.exists());
    std::fs::write(&photo, b"bad now").unwrap();
    convert_batch(
        std::slice::from_ref(&photo),
        &OutLayout::BesidePhoto,
        false,
        &conv,
        |_| {},
    );
    assert!(
        !marker.exists(),
        "a failed reconversion must not keep the old marker"
    );
}
