//! The framebuffer sink against regular files standing in for /dev/fb0: the packed pixel
//! values, the row stride (padding bytes untouched) and frames of another size.

use std::path::Path;

use image::{Rgb, RgbImage};
use reshader::device::display::{open_sink, FbGeometry, FrameSink, FramebufferSink};

/// A file of `len` bytes, all 0xAA, so untouched bytes are recognisable.
fn fake_fb(path: &Path, len: usize) {
    std::fs::write(path, vec![0xAA; len]).unwrap();
}

fn test_frame() -> RgbImage {
    RgbImage::from_fn(3, 2, |x, y| match (x, y) {
        (0, 0) => Rgb([255, 0, 0]),
        (1, 0) => Rgb([0, 255, 0]),
        (2, 0) => Rgb([0, 0, 255]),
        (0, 1) => Rgb([255, 255, 255]),
        (1, 1) => Rgb([0x12, 0x34, 0x56]),
        _ => Rgb([0, 0, 0]),
    })
}

#[test]
fn xrgb8888_with_padded_stride() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fb0");
    // 3 pixels of 4 bytes = 12 bytes of picture in a 16-byte row.
    let geometry = FbGeometry::parse("3x2:xrgb8888:16").unwrap();
    fake_fb(&path, 32);
    let mut sink = FramebufferSink::open_with_geometry(&path, geometry).unwrap();
    assert!(
        sink.describe().contains("3x2 visible"),
        "{}",
        sink.describe()
    );
    assert!(
        sink.describe().contains("stride 16 B"),
        "{}",
        sink.describe()
    );
    sink.show(&test_frame()).unwrap();
    drop(sink);

    let mem = std::fs::read(&path).unwrap();
    let px = |x: usize, y: usize| {
        u32::from_le_bytes(mem[y * 16 + x * 4..y * 16 + x * 4 + 4].try_into().unwrap())
    };
    assert_eq!(px(0, 0), 0x00FF_0000);
    assert_eq!(px(1, 0), 0x0000_FF00);
    assert_eq!(px(2, 0), 0x0000_00FF);
    assert_eq!(px(0, 1), 0x00FF_FFFF);
    assert_eq!(px(1, 1), 0x0012_3456);
    assert_eq!(px(2, 1), 0);
    for row in 0..2 {
        assert_eq!(
            &mem[row * 16 + 12..row * 16 + 16],
            &[0xAA; 4],
            "row {row} padding"
        );
    }
}

#[test]
fn rgb565_with_padded_stride() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fb1");
    // 3 pixels of 2 bytes = 6 bytes of picture in a 10-byte row.
    let geometry = FbGeometry::parse("3x2:rgb565:10").unwrap();
    fake_fb(&path, 20);
    let mut sink = FramebufferSink::open_with_geometry(&path, geometry).unwrap();
    sink.show(&test_frame()).unwrap();
    drop(sink);

    let mem = std::fs::read(&path).unwrap();
    let px =
        |x: usize, y: usize| u16::from_le_bytes([mem[y * 10 + x * 2], mem[y * 10 + x * 2 + 1]]);
    assert_eq!(px(0, 0), 0xF800);
    assert_eq!(px(1, 0), 0x07E0);
    assert_eq!(px(2, 0), 0x001F);
    assert_eq!(px(0, 1), 0xFFFF);
    // 0x12 = 18 → 18·31/255 = 2.19 → 2; 0x34 = 52 → 52·63/255 = 12.85 → 13;
    // 0x56 = 86 → 86·31/255 = 10.45 → 10.
    assert_eq!(px(1, 1), (2 << 11) | (13 << 5) | 10);
    for row in 0..2 {
        assert_eq!(
            &mem[row * 10 + 6..row * 10 + 10],
            &[0xAA; 4],
            "row {row} padding"
        );
    }
}

#[test]
fn frames_of_another_size_are_cropped_or_bordered_not_scaled() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fb2");
    fake_fb(&path, 4 * 4 * 2);
    let mut sink =
        FramebufferSink::open_with_geometry(&path, FbGeometry::parse("4x2:xrgb8888").unwrap())
            .unwrap();
    sink.show(&RgbImage::from_pixel(2, 1, Rgb([9, 9, 9])))
        .unwrap();
    drop(sink);
    let mem = std::fs::read(&path).unwrap();
    let px =
        |x: usize, y: usize| u32::from_le_bytes(mem[y * 16 + x * 4..][..4].try_into().unwrap());
    assert_eq!((px(0, 0), px(1, 0)), (0x0009_0909, 0x0009_0909));
    assert_eq!(
        (px(2, 0), px(0, 1), px(3, 1)),
        (0, 0, 0),
        "outside the frame is black"
    );
}

#[test]
fn a_file_too_small_for_its_geometry_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small");
    fake_fb(&path, 10);
    let err = FramebufferSink::open_with_geometry(&path, FbGeometry::parse("4x4:rgb565").unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("file has 10 B, the geometry needs 32 B"),
        "{err}"
    );
}

#[test]
fn a_regular_file_needs_an_explicit_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain");
    fake_fb(&path, 64);
    let spec = format!("fb:{}", path.display());
    let err = open_sink(&spec, dir.path()).err().unwrap().to_string();
    assert!(err.contains("not a framebuffer device"), "{err}");
    let spec = format!("fb:{}:4x4:xrgb8888", path.display());
    let sink = open_sink(&spec, dir.path()).unwrap();
    assert!(
        sink.describe().contains("4x4 visible"),
        "{}",
        sink.describe()
    );
}

/// Reads the geometry of a real framebuffer where one exists; elsewhere says so.
#[test]
fn real_framebuffer_when_present() {
    let path = Path::new("/dev/fb0");
    if !path.exists() {
        eprintln!("SKIPPED real_framebuffer_when_present: no /dev/fb0 on this machine");
        return;
    }
    match FramebufferSink::open(path) {
        Ok(sink) => eprintln!("found {}", sink.describe()),
        Err(e) => eprintln!("SKIPPED real_framebuffer_when_present: {e}"),
    }
}
