//! Corrupt and unusual photos in one `reshader convert` batch: each either converts or
//! fails with a message of its own that names it, and the batch goes on to the end.
//!
//! The JPEG forms `image` cannot write (CMYK, progressive) come from a small encoder
//! below that codes flat 8x8 blocks (DC coefficients only). Every photo gets a depth
//! sidecar so that the test does not depend on the depth network.

use crate::spine_support;

use std::path::Path;
use std::process::Command;

use image::{DynamicImage, ImageFormat, Rgb, RgbImage};
use spine_support::*;

/// Bits written most significant first, with JPEG's 0xFF byte stuffing.
struct Bits {
    out: Vec<u8>,
    acc: u8,
    len: u32,
}

impl Bits {
    fn put(&mut self, value: u32, len: u32) {
        for i in (0..len).rev() {
            self.acc = (self.acc << 1) | ((value >> i) & 1) as u8;
            self.len += 1;
            if self.len == 8 {
                self.out.push(self.acc);
                if self.acc == 0xFF {
                    self.out.push(0);
                }
                (self.acc, self.len) = (0, 0);
            }
        }
    }

    fn finish(mut self) -> Vec<u8> {
        while self.len != 0 {
            self.put(1, 1);
        }
        self.out
    }
}

fn segment(marker: u8, payload: &[u8]) -> Vec<u8> {
    let mut s = vec![0xFF, marker];
    s.extend_from_slice(&((payload.len() + 2) as u16).to_be_bytes());
    s.extend_from_slice(payload);
    s
}

/// A JPEG of `w`×`h` (multiples of 8) whose 8x8 blocks are flat, with `channels` 1, 3 or
/// 4 components (4 = CMYK, with an Adobe segment), baseline or progressive (one DC scan).
fn flat_block_jpeg(w: u16, h: u16, channels: u8, progressive: bool) -> Vec<u8> {
    let mut jpeg = vec![0xFF, 0xD8];
    if channels == 4 {
        // Adobe APP14, transform 0: the components are C, M, Y, K as stored.
        jpeg.extend(segment(0xEE, b"Adobe\x00\x64\x00\x00\x00\x00\x00"));
    }
    let mut dqt = vec![0u8];
    dqt.extend([1u8; 64]);
    jpeg.extend(segment(0xDB, &dqt));
    let mut sof = vec![8];
    sof.extend(h.to_be_bytes());
    sof.extend(w.to_be_bytes());
    sof.push(channels);
    for c in 1..=channels {
        sof.extend([c, 0x11, 0]);
    }
    jpeg.extend(segment(if progressive { 0xC2 } else { 0xC0 }, &sof));
    // DC table: categories 0..=11, all with 4-bit codes (code = category). AC table: only
    // end-of-block, code "0".
    let mut dht = vec![0x00, 0, 0, 0, 12];
    dht.extend([0u8; 12]);
    dht.extend(0..12u8);
    dht.extend([0x10, 1]);
    dht.extend([0u8; 15]);
    dht.push(0x00);
    jpeg.extend(segment(0xC4, &dht));
    let mut sos = vec![channels];
    for c in 1..=channels {
        sos.extend([c, 0x00]);
    }
    sos.extend([0, if progressive { 0 } else { 63 }, 0]);
    jpeg.extend(segment(0xDA, &sos));
    let mut bits = Bits {
        out: Vec::new(),
        acc: 0,
        len: 0,
    };
    let mut previous = vec![0i32; usize::from(channels)];
    for by in 0..h / 8 {
        for bx in 0..w / 8 {
            for (c, previous) in previous.iter_mut().enumerate() {
                let level = (i32::from(bx) * 50 + i32::from(by) * 90 + c as i32 * 70) % 256;
                // With unit quantisation a flat block's DC is 8 × (level − 128).
                let dc = 8 * (level - 128);
                let diff = dc - *previous;
                *previous = dc;
                let category = 32 - diff.unsigned_abs().leading_zeros();
                bits.put(category, 4);
                let extra = if diff < 0 { diff - 1 } else { diff };
                bits.put(extra as u32 & ((1 << category) - 1), category);
                if !progressive {
                    bits.put(0, 1);
                }
            }
        }
    }
    jpeg.extend(bits.finish());
    jpeg.extend([0xFF, 0xD9]);
    jpeg
}

fn encoded(image: DynamicImage, format: ImageFormat) -> Vec<u8> {
    let mut bytes = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .unwrap();
    bytes
}

fn textured(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let v = (x * 7919 + y * 104_729) % 251;
        Rgb([v as u8, (x * 8) as u8, (y * 8) as u8])
    })
}

/// A JPEG with a maximal (64 KB) EXIF segment whose first directory claims 65535
/// entries, far more than the segment holds.
fn huge_exif_jpeg(w: u32, h: u32) -> Vec<u8> {
    let plain = encoded(DynamicImage::ImageRgb8(textured(w, h)), ImageFormat::Jpeg);
    let mut exif = b"Exif\0\0MM\0\x2a\0\0\0\x08\xff\xff".to_vec();
    exif.resize(65_533, 0x41);
    let mut jpeg = plain[..2].to_vec();
    jpeg.extend(segment(0xE1, &exif));
    jpeg.extend(&plain[2..]);
    jpeg
}

/// A JPEG whose frame header claims `w`×`h` though its data is for 16x8.
fn jpeg_claiming(w: u16, h: u16) -> Vec<u8> {
    let mut jpeg = flat_block_jpeg(16, 8, 3, false);
    let sof = jpeg.windows(2).position(|m| m == [0xFF, 0xC0]).unwrap();
    jpeg[sof + 5..sof + 7].copy_from_slice(&h.to_be_bytes());
    jpeg[sof + 7..sof + 9].copy_from_slice(&w.to_be_bytes());
    jpeg
}

/// What one photo of the corpus is, and what converting it must give.
struct Case {
    name: &'static str,
    bytes: Vec<u8>,
    /// Size of the depth sidecar, which the photo's aspect must match.
    size: (u32, u32),
    /// `None`: converts. `Some(text)`: fails with a message containing `text`.
    error: Option<&'static str>,
}

fn corpus() -> Vec<Case> {
    let rgb = DynamicImage::ImageRgb8(textured(32, 16));
    let jpeg = encoded(rgb.clone(), ImageFormat::Jpeg);
    let png = encoded(rgb.clone(), ImageFormat::Png);
    let case = |name, bytes, error| Case {
        name,
        bytes,
        size: (32, 16),
        error,
    };
    vec![
        case("zero_length.jpg", Vec::new(), Some("empty file")),
        case(
            "cut_short.png",
            png[..png.len() / 2].to_vec(),
            Some("cannot decode"),
        ),
        case(
            "not_a_photo.jpg",
            b"GIF? no: plain text".to_vec(),
            Some("cannot decode"),
        ),
        case("png_named.jpg", png.clone(), None),
        // The JPEG decoder fills the missing half with grey and reports success; the
        // photo must fail instead, naming itself.
        case(
            "truncated.jpg",
            jpeg[..jpeg.len() * 2 / 3].to_vec(),
            Some("truncated"),
        ),
        case("cmyk.jpg", flat_block_jpeg(32, 16, 4, false), None),
        case("progressive.jpg", flat_block_jpeg(32, 16, 3, true), None),
        case("grey_flat.jpg", flat_block_jpeg(32, 16, 1, false), None),
        case(
            "sixteen_bit.png",
            encoded(DynamicImage::ImageRgb16(rgb.to_rgb16()), ImageFormat::Png),
            None,
        ),
        case(
            "alpha.png",
            encoded(DynamicImage::ImageRgba8(rgb.to_rgba8()), ImageFormat::Png),
            None,
        ),
        case(
            "grey.png",
            encoded(DynamicImage::ImageLuma8(rgb.to_luma8()), ImageFormat::Png),
            None,
        ),
        case("huge_exif.jpg", huge_exif_jpeg(32, 16), None),
        case(
            "huge_frame.jpg",
            jpeg_claiming(60_000, 60_000),
            Some("60000x60000"),
        ),
        // Within the side limit, but 16000² pixels exceed a quarter of --max-memory.
        case(
            "over_budget.jpg",
            jpeg_claiming(16_000, 16_000),
            Some("--max-memory"),
        ),
        Case {
            name: "huge_header.png",
            bytes: png_claiming(100_000, 100_000),
            size: (32, 16),
            error: Some("100000x100000"),
        },
    ]
}

/// A valid 1x1 PNG whose header claims another size (the CRC patched to match).
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let mut png = encoded(
        DynamicImage::ImageRgb8(RgbImage::new(1, 1)),
        ImageFormat::Png,
    );
    png[16..20].copy_from_slice(&width.to_be_bytes());
    png[20..24].copy_from_slice(&height.to_be_bytes());
    let mut crc = !0u32;
    for &b in &png[12..29] {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    png[29..33].copy_from_slice(&(!crc).to_be_bytes());
    png
}

fn write_case(dir: &Path, case: &Case) -> String {
    let path = dir.join(case.name);
    std::fs::write(&path, &case.bytes).unwrap();
    let stem = case.name.rsplit_once('.').unwrap().0;
    let (w, h) = case.size;
    let depth: Vec<f32> = (0..w * h).map(|i| 2.0 + (i % w) as f32 * 0.05).collect();
    write_npy(
        &dir.join(format!("{stem}_depth.npy")),
        h as usize,
        w as usize,
        &depth,
    );
    path.display().to_string()
}

#[test]
fn every_corrupt_photo_converts_or_fails_alone_with_its_own_message() {
    let dir = tempfile::tempdir().unwrap();
    let photos_dir = dir.path().join("photos");
    std::fs::create_dir_all(&photos_dir).unwrap();
    let cases = corpus();
    let paths: Vec<String> = cases.iter().map(|c| write_case(&photos_dir, c)).collect();
    let out = dir.path().join("out").display().to_string();
    let board = tiny_board();
    let output = Command::new(env!("CARGO_BIN_EXE_reshader"))
        .env("RESHADER_MODEL", "none")
        .args(["convert", "--board", &board, "--out", &out, "--json"])
        .args(&paths)
        .output()
        .unwrap();
    // Some photos fail, so the batch as a whole does.
    assert!(!output.status.success());
    let stdout = String::from_utf8(output.stdout).unwrap();
    let reports: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(reports.len(), cases.len(), "a report per photo: {stdout}");
    let mut messages = Vec::new();
    for (case, report) in cases.iter().zip(&reports) {
        let photo = report["photo"].as_str().unwrap();
        assert!(photo.ends_with(case.name), "reports out of order: {photo}");
        let status = report["status"].as_str().unwrap();
        match case.error {
            None => {
                assert_eq!(status, "converted", "{}: {report}", case.name);
                let panel = Path::new(&out).join(case.name.split('.').next().unwrap());
                let frame = load(&panel.join("panel.png"));
                assert_eq!(frame.dimensions(), (64, 48), "{}", case.name);
            }
            Some(expected) => {
                assert_eq!(status, "failed", "{}: {report}", case.name);
                let error = report["error"].as_str().unwrap();
                assert!(error.contains(case.name), "{}: {error}", case.name);
                assert!(error.contains(expected), "{}: {error}", case.name);
                assert!(!error.contains("internal error"), "{}: {error}", case.name);
                messages.push(error.replace(case.name, ""));
            }
        }
    }
    // Each failure says what is wrong with its own photo, not one generic line.
    let distinct: std::collections::BTreeSet<&String> = messages.iter().collect();
    assert_eq!(distinct.len(), messages.len(), "{messages:#?}");
}

#[test]
fn flat_block_encoder_writes_what_image_decodes() {
    // The hand-made JPEGs are only meaningful if they decode to the intended blocks.
    let grey = image::load_from_memory(&flat_block_jpeg(16, 8, 1, false)).unwrap();
    let grey = grey.to_luma8();
    assert_eq!(grey.dimensions(), (16, 8));
    assert_eq!(grey.get_pixel(3, 3).0[0], 0);
    assert_eq!(grey.get_pixel(12, 3).0[0], 50);
    let progressive = image::load_from_memory(&flat_block_jpeg(16, 8, 3, true)).unwrap();
    assert_eq!(progressive.to_rgb8().dimensions(), (16, 8));
}
