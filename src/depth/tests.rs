//! Unit tests of `depth`, beside it so that the module file holds the code only.

use super::*;
use crate::io::npy;

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// [`DepthMap::load`] for a grey photo of `w`×`h`, refusing holes.
fn load(
    path: &Path,
    kind: DepthKind,
    w: u32,
    h: u32,
) -> Result<(DepthMap, DepthReport), DepthError> {
    DepthMap::load(path, kind, HolePolicy::Refuse, &SrgbImage::new(w, h))
}

fn ramp(w: usize, h: usize) -> DepthMap {
    DepthMap::new(w, h, (0..w * h).map(|i| 1.0 + i as f32 * 0.25).collect())
}

#[test]
fn every_writer_roundtrips_through_its_reader() {
    let dir = tempfile::tempdir().unwrap();
    let map = ramp(4, 3);
    for ext in ["npy", "pfm", "exr", "png"] {
        let path = dir.path().join(format!("d.{ext}"));
        std::fs::write(&path, map.encode(&path).unwrap()).unwrap();
        let (back, report) = load(&path, DepthKind::Depth, 4, 3).unwrap();
        assert_eq!(report.resized_to, None);
        for (a, b) in back.data().iter().zip(map.data()) {
            assert!((a - b).abs() < 1e-3, "{ext}: {a} vs {b}");
        }
    }
}

#[test]
fn rgb_exr_depth_comes_from_red() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb.exr");
    let rgb: Vec<f32> = (0..6).flat_map(|i| [1.0 + i as f32, 0.0, 9.0]).collect();
    image::Rgb32FImage::from_raw(3, 2, rgb)
        .unwrap()
        .save(&path)
        .unwrap();
    let raw = read_raw(&path).unwrap();
    assert_eq!((raw.width, raw.height), (3, 2));
    assert_eq!(raw.values, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
}

#[test]
fn relative_disparity_maps_percentiles_to_training_range() {
    let raw = RawMap {
        width: 101,
        height: 1,
        values: (0..101).map(|i| i as f32 * 10.0 - 300.0).collect(),
    };
    let (map, [lo, hi]) = DepthMap::from_relative_disparity(&raw);
    assert_eq!((lo, hi), (-280.0, 680.0));
    assert!((map.at(2, 0) - FAR).abs() < 1e-4);
    assert!((map.at(98, 0) - NEAR).abs() < 1e-4);
    // Larger disparity is nearer, monotonically.
    assert!(map.data().windows(2).all(|w| w[1] <= w[0]));
    let [min, max] = map.range();
    assert!(min >= NEAR / 2.0 && max <= 10.0 * FAR);
}

#[test]
fn nan_constant_nonpositive_and_aspect_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let nan = write(
        dir.path(),
        "nan.npy",
        &npy::encode_f32(&[2, 2], &[1.0, f32::NAN, 2.0, f32::INFINITY]),
    );
    let err = load(&nan, DepthKind::Depth, 2, 2).unwrap_err();
    assert!(
        matches!(
            err,
            DepthError::Holes {
                count: 2,
                x: 1,
                y: 0,
                ..
            }
        ),
        "{err}"
    );
    let none = write(dir.path(), "none.npy", &npy::encode_f32(&[1, 2], &[0.0; 2]));
    let err = load(&none, DepthKind::Depth, 2, 1).unwrap_err();
    assert!(matches!(err, DepthError::NoDepth { .. }), "{err}");
    let flat = write(dir.path(), "flat.npy", &npy::encode_f32(&[2, 2], &[3.0; 4]));
    let err = load(&flat, DepthKind::Disparity, 2, 2).unwrap_err();
    assert!(matches!(err, DepthError::Constant { .. }), "{err}");
    let neg = write(
        dir.path(),
        "neg.npy",
        &npy::encode_f32(&[1, 2], &[1.0, -1.0]),
    );
    let err = load(&neg, DepthKind::Depth, 2, 1).unwrap_err();
    assert!(matches!(err, DepthError::NonPositive { x: 1, .. }), "{err}");
    assert!(load(&neg, DepthKind::Disparity, 2, 1).is_ok());
    let err = load(&neg, DepthKind::Disparity, 1, 2).unwrap_err();
    assert!(err.to_string().contains("aspect"), "{err}");
}

#[test]
fn resizing_keeps_a_constant_region_constant() {
    let mut data = vec![2.0; 8 * 8];
    data[0] = 4.0;
    let map = DepthMap::new(8, 8, data).resized(16, 16);
    assert_eq!((map.width(), map.height()), (16, 16));
    assert!((map.at(15, 15) - 2.0).abs() < 1e-6);
    assert!(map.at(0, 0) > 2.0);
}

/// `bytes` with the first occurrence of `find` replaced.
fn patched(bytes: &[u8], find: &[u8], with: &[u8]) -> Vec<u8> {
    let at = bytes
        .windows(find.len())
        .position(|w| w == find)
        .expect("pattern present");
    let mut out = bytes.to_vec();
    out[at..at + with.len()].copy_from_slice(with);
    out
}

#[test]
fn absurd_sizes_are_refused_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let map = ramp(4, 3);
    // An EXR whose data window claims 30000x30000 (3.4 GiB of floats).
    let exr = map.encode(Path::new("d.exr")).unwrap();
    let mut window = b"dataWindow\0box2i\0\x10\0\0\0".to_vec();
    let mut claim = window.clone();
    window.extend(
        [0u8; 8]
            .iter()
            .chain(&3u32.to_le_bytes())
            .chain(&2u32.to_le_bytes()),
    );
    claim.extend(
        [0u8; 8]
            .iter()
            .chain(&29_999u32.to_le_bytes())
            .chain(&29_999u32.to_le_bytes()),
    );
    let path = write(dir.path(), "huge.exr", &patched(&exr, &window, &claim));
    let err = read_raw(&path).unwrap_err();
    assert!(matches!(err, DepthError::TooLarge { .. }), "{err}");
    assert!(err.to_string().contains("huge.exr"), "{err}");
    assert!(err.to_string().contains("30000x30000"), "{err}");
    // A 16-bit PNG claiming 100000x100000.
    let png = map.encode(Path::new("d.png")).unwrap();
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend(
        100_000u32
            .to_be_bytes()
            .iter()
            .chain(&100_000u32.to_be_bytes()),
    );
    let mut png = patched(&png, b"IHDR", &ihdr);
    let crc = crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    let path = write(dir.path(), "huge.png", &png);
    let err = read_raw(&path).unwrap_err();
    assert!(matches!(err, DepthError::Size { .. }), "{err}");
    assert!(err.to_string().contains("100000x100000"), "{err}");
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

#[test]
fn eight_bit_png_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d8.png");
    image::GrayImage::from_raw(2, 1, vec![1, 2])
        .unwrap()
        .save(&path)
        .unwrap();
    let err = read_raw(&path).unwrap_err();
    assert!(err.to_string().contains("16-bit"), "{err}");
}
