//! Unit tests of `device::gallery::watch`, beside it so that the module file holds the code only.

use super::*;

#[test]
fn only_visible_photos_that_are_not_depth_maps_are_watched() {
    for yes in ["a.jpg", "B.JPEG", "c.png", "my.photo.jpg"] {
        assert!(is_watched_photo(Path::new(yes)), "{yes}");
    }
    for no in [
        ".a.jpg",
        "a.jpg.tmp",
        "a_depth.png",
        "a_disparity.png",
        "a.npy",
        "jpg",
    ] {
        assert!(!is_watched_photo(Path::new(no)), "{no}");
    }
}

#[test]
fn a_growing_file_waits_until_it_settles() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.jpg");
    std::fs::write(&photo, b"part").unwrap();
    let mut state = State::default();
    state.note(&photo, WriteState::Unknown);
    let hour = Duration::from_secs(3600);
    assert!(state.ready(hour).is_empty());
    std::fs::write(&photo, b"partial plus more").unwrap();
    assert!(
        state.ready(Duration::ZERO).is_empty(),
        "a change restarts the settle time"
    );
    assert!(
        state.ready(Duration::ZERO).is_empty(),
        "one poll does not show the size is stable"
    );
    assert_eq!(state.ready(Duration::ZERO), std::slice::from_ref(&photo));
    state.handled(&photo);
    state.note(&photo, WriteState::Closed);
    assert!(
        state.ready(Duration::ZERO).is_empty(),
        "an unchanged file is not redone"
    );
    std::fs::write(&photo, b"edited").unwrap();
    state.note(&photo, WriteState::Closed);
    assert!(state.ready(hour).is_empty());
    assert_eq!(
        state.ready(hour),
        [photo],
        "an edited, closed file is redone"
    );
}

#[test]
fn a_file_open_for_writing_waits_for_its_close() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.png");
    std::fs::write(&photo, b"first half").unwrap();
    let mut state = State::default();
    state.note(&photo, WriteState::Writing);
    // Quiet for twice the settle time, far less than OPEN_WRITER_LIMIT of them.
    let settle = Duration::from_millis(10);
    std::thread::sleep(settle * 2);
    assert!(
        state.ready(settle).is_empty(),
        "a paused writer is not complete"
    );
    state.note(&photo, WriteState::Closed);
    assert_eq!(state.ready(Duration::from_secs(3600)), [photo]);
}

#[test]
fn a_closed_file_is_ready_once_two_polls_find_it_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.png");
    std::fs::write(&photo, b"complete").unwrap();
    let mut state = State::default();
    state.note(&photo, WriteState::Closed);
    let hour = Duration::from_secs(3600);
    assert!(state.ready(hour).is_empty());
    assert_eq!(state.ready(hour), [photo]);
}

fn jpeg_bytes() -> Vec<u8> {
    let img = image::RgbImage::from_fn(32, 16, |x, y| image::Rgb([x as u8 * 8, y as u8, 9]));
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Jpeg,
    )
    .unwrap();
    bytes
}

/// A writer that closes a photo it has not finished (a copy in pieces): the
/// half-written JPEG is not converted until its end arrives.
#[test]
fn a_closed_but_cut_off_photo_waits_for_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.jpg");
    let jpeg = jpeg_bytes();
    std::fs::write(&photo, &jpeg[..jpeg.len() / 2]).unwrap();
    let mut state = State::default();
    state.note(&photo, WriteState::Closed);
    let hour = Duration::from_secs(3600);
    for _ in 0..4 {
        assert!(state.ready(hour).is_empty(), "a cut-off JPEG was ready");
    }
    std::fs::write(&photo, &jpeg).unwrap();
    state.note(&photo, WriteState::Closed);
    assert!(state.ready(hour).is_empty());
    assert_eq!(state.ready(hour), std::slice::from_ref(&photo));
    state.handled(&photo);
    // A PNG without its IEND chunk waits too; past the writer limit it goes on (to
    // fail as truncated) rather than wait forever.
    let png = dir.path().join("q.png");
    std::fs::write(&png, b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR").unwrap();
    state.note(&png, WriteState::Closed);
    assert!(state.ready(hour).is_empty());
    assert!(state.ready(hour).is_empty());
    assert_eq!(state.ready(Duration::ZERO), [png]);
}

#[test]
fn a_changed_depth_sidecar_sends_its_photo_round_again() {
    let dir = tempfile::tempdir().unwrap();
    let photo = dir.path().join("p.jpg");
    std::fs::write(&photo, b"photo").unwrap();
    let mut state = State::default();
    state.note(&photo, WriteState::Closed);
    state.ready(Duration::ZERO);
    assert_eq!(state.ready(Duration::ZERO), std::slice::from_ref(&photo));
    state.handled(&photo);
    let sidecar = dir.path().join("p_depth.npy");
    std::fs::write(&sidecar, b"depth").unwrap();
    assert_eq!(sidecar_of(&sidecar).as_deref(), Some("p"));
    state.note(&sidecar, WriteState::Closed);
    state.ready(Duration::ZERO);
    assert_eq!(state.ready(Duration::ZERO), std::slice::from_ref(&photo));
    state.handled(&photo);
    // Seen again unchanged (a rescan): nothing to do.
    state.note(&sidecar, WriteState::Unknown);
    state.ready(Duration::ZERO);
    assert!(state.ready(Duration::ZERO).is_empty());
}
