//! Depth embedded in JPEGs: fixtures written here by embedding a known 16-bit depth PNG
//! as Google GDepth XMP (in Extended XMP chunks, out of order) and as an Android Dynamic
//! Depth container (items appended after the JPEG), read back by the runtime; corrupt
//! metadata and containers must give errors that say what is wrong.

use crate::depth_support;

use std::path::{Path, PathBuf};

use depth_support::*;
use reshader::depth::embedded::{self as embedded_depth, Container, EmbeddedError, RangeFormat};

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn expected(normalised: &[f32], format: RangeFormat, near: f32, far: f32) -> Vec<f32> {
    normalised
        .iter()
        .map(|&v| match format {
            RangeFormat::RangeLinear => near + v * (far - near),
            RangeFormat::RangeInverse => far * near / (far - v * (far - near)),
        })
        .collect()
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() <= 1e-6 * w, "pixel {i}: {g} vs {w}");
    }
}

#[test]
fn gdepth_in_extended_xmp_reads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (png, normalised) = depth_png(20, 15);
    for format in [RangeFormat::RangeInverse, RangeFormat::RangeLinear] {
        let name = format!("{format:?}");
        // 700-byte chunks: several segments, written last first.
        let path = write(dir.path(), "g.jpg", &gdepth_jpeg(&base64(&png), &name, 700));
        let found = embedded_depth::read(&path).unwrap().expect("depth found");
        assert_eq!(found.container, Container::GDepth);
        assert_eq!(found.format, format);
        assert_eq!((found.near, found.far), (0.5, 4.25));
        assert_eq!(found.units.as_deref(), Some("m"));
        assert_eq!((found.map.width, found.map.height), (20, 15));
        assert_close(&found.map.values, &expected(&normalised, format, 0.5, 4.25));
    }
}

#[test]
fn dynamic_depth_container_reads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (png, normalised) = depth_png(20, 15);
    let path = write(dir.path(), "dd.jpg", &dynamic_depth_jpeg(&png, png.len()));
    let found = embedded_depth::read(&path).unwrap().expect("depth found");
    assert_eq!(found.container, Container::DynamicDepth);
    assert_eq!(found.format, RangeFormat::RangeLinear);
    assert_eq!(found.units.as_deref(), Some("Meters"));
    assert_close(
        &found.map.values,
        &expected(&normalised, RangeFormat::RangeLinear, 0.25, 8.0),
    );
}

#[test]
fn photo_without_depth_gives_none() {
    let dir = tempfile::tempdir().unwrap();
    let plain = write(dir.path(), "plain.jpg", &photo_jpeg(16, 16));
    assert!(embedded_depth::read(&plain).unwrap().is_none());
    let other_xmp = with_segments(
        &photo_jpeg(16, 16),
        &[standard_xmp(
            r#"<rdf:Description xmlns:dc="http://purl.org/dc/elements/1.1/" dc:format="image/jpeg"/>"#,
        )],
    );
    let path = write(dir.path(), "xmp.jpg", &other_xmp);
    assert!(embedded_depth::read(&path).unwrap().is_none());
}

fn error_of(dir: &Path, bytes: &[u8]) -> String {
    let path = write(dir, "bad.jpg", bytes);
    match embedded_depth::read(&path) {
        Err(e @ EmbeddedError::Malformed { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("bad.jpg"),
                "error does not name the file: {text}"
            );
            text
        }
        other => panic!("expected a malformed-depth error, got {other:?}"),
    }
}

#[test]
fn corrupt_metadata_and_containers_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let dir = dir.path();
    let (png, _) = depth_png(20, 15);
    let b64 = base64(&png);

    let bad_b64 = gdepth_jpeg(&b64.replacen('A', "*", 1), "RangeLinear", 700);
    assert!(error_of(dir, &bad_b64).contains("not base64"));

    let bad_format = gdepth_jpeg(&b64, "Squared", 700);
    assert!(error_of(dir, &bad_format).contains("GDepth:Format is \"Squared\""));

    // Drop one Extended XMP chunk: the packet has a hole.
    let full = gdepth_jpeg(&b64, "RangeLinear", 700);
    let marker = b"http://ns.adobe.com/xmp/extension/\0";
    let at = full
        .windows(marker.len())
        .position(|w| w == marker)
        .unwrap()
        - 4;
    let len = usize::from(u16::from_be_bytes([full[at + 2], full[at + 3]])) + 2;
    let holed = [&full[..at], &full[at + len..]].concat();
    assert!(error_of(dir, &holed).contains("incomplete"));

    let not_png = gdepth_jpeg(&base64(b"definitely not a png"), "RangeLinear", 700);
    assert!(error_of(dir, &not_png).contains("cannot decode the depth image"));

    let unclosed = with_segments(
        &photo_jpeg(16, 16),
        &[standard_xmp(
            r#"<rdf:Description xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/"><GDepth:Format>RangeLinear"#,
        )],
    );
    assert!(error_of(dir, &unclosed).contains("XMP"));

    let too_long = dynamic_depth_jpeg(&png, png.len() + 10_000);
    assert!(error_of(dir, &too_long).contains("more bytes than"));

    let mut truncated_segment = photo_jpeg(16, 16)[..2].to_vec();
    truncated_segment.extend_from_slice(&[0xFF, 0xE1, 0x40, 0x00, b'h', b't']);
    assert!(error_of(dir, &truncated_segment).contains("beyond the file"));
}
