//! Loading the input photo: decoding with allocation limits, EXIF orientation and the
//! horizontal field of view.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::imageops::FilterType;
use image::{DynamicImage, ImageDecoder, ImageFormat, ImageReader, Rgb32FImage, RgbImage};

use crate::io::limits::{self, ReadError, TooLarge};

/// Horizontal field of view assumed when the photo carries no usable metadata.
pub const DEFAULT_HFOV_DEG: f64 = 45.0;

/// Larger photos are refused before their pixels are allocated: a phone photo is ~12k px
/// on its long side at most, and a hostile header can claim 4 billion.
pub const MAX_PHOTO_SIDE: u32 = 16_384;
/// Bytes per pixel a photo takes while loading, besides the decoder's own buffer: the
/// 8-bit RGB copy and the float RGB image the pipeline works on.
const WORKING_BYTES_PER_PIXEL: u64 = 3 + 12;

/// The diagonal of a 36×24 mm frame, which defines "35 mm equivalent" focal lengths.
const FULL_FRAME_DIAGONAL_MM: f64 = 43.266_615;

#[derive(Debug, thiserror::Error)]
pub enum PhotoError {
    #[error("cannot read photo {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot decode photo {path}: {source}")]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("photo {path} is empty (0 pixels)")]
    Empty { path: PathBuf },
    #[error("photo {path} is an empty file (0 bytes)")]
    EmptyFile { path: PathBuf },
    #[error("photo {path} is {width}x{height} pixels; photos may be at most {MAX_PHOTO_SIDE} pixels a side")]
    Size {
        path: PathBuf,
        width: u32,
        height: u32,
    },
    #[error("photo {path}: {source}")]
    TooLarge { path: PathBuf, source: TooLarge },
    #[error("field of view {0}° is outside (0°, 180°)")]
    BadFov(f64),
    #[error(
        "photo {path} is truncated: {detail} after {len} bytes (was it still being \
         written or cut short in a transfer?)"
    )]
    Truncated {
        path: PathBuf,
        len: usize,
        detail: &'static str,
    },
}

/// One 8-bit level in [0, 1] values: the smallest change a display shows.
pub const ONE_LEVEL: f32 = 1.0 / 255.0;

/// RGB image whose values are sRGB-encoded (not linear) in [0, 1]: the colour space the
/// reshading network is trained on, and the one PNG files store.
#[derive(Clone, Debug, PartialEq)]
pub struct SrgbImage {
    width: u32,
    height: u32,
    data: Vec<f32>,
}

/// An encoded value in 0..=1 as the nearest 8-bit level (clamped; NaN as 0).
#[inline]
pub fn byte(v: f32) -> u8 {
    // floor(y + 0.5) in f64 is exactly f32::round for 0 <= y <= 255 (the sum needs at
    // most 33 bits), and unlike round() it compiles to vector code.
    (f64::from(v.clamp(0.0, 1.0) * 255.0) + 0.5) as u8
}

impl SrgbImage {
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width as usize * height as usize * 3],
        }
    }

    pub fn from_rgb8(image: &RgbImage) -> Self {
        Self {
            width: image.width(),
            height: image.height(),
            data: image
                .as_raw()
                .iter()
                .map(|&v| f32::from(v) / 255.0)
                .collect(),
        }
    }

    pub fn from_rgb32f(image: Rgb32FImage) -> Self {
        Self {
            width: image.width(),
            height: image.height(),
            data: image.into_raw(),
        }
    }

    pub fn to_rgb8(&self) -> RgbImage {
        let bytes = self.data.iter().map(|&v| byte(v)).collect();
        RgbImage::from_raw(self.width, self.height, bytes).expect("buffer matches size")
    }

    pub fn to_rgb32f(&self) -> Rgb32FImage {
        Rgb32FImage::from_raw(self.width, self.height, self.data.clone())
            .expect("buffer matches size")
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn data(&self) -> &[f32] {
        &self.data
    }

    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        let i = self.index(x, y);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    pub fn put(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// Resamples with a filter whose support grows with the reduction, so that
    /// downscaling averages areas instead of aliasing.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        // Resampled from the pixels in place: a copy of a 12-megapixel photo would be
        // 144 MB more at the moment a render's memory peaks.
        let source = image::ImageBuffer::<image::Rgb<f32>, &[f32]>::from_raw(
            self.width,
            self.height,
            &self.data,
        )
        .expect("buffer matches size");
        let resized = image::imageops::resize(&source, width, height, FilterType::Triangle);
        Self::from_rgb32f(resized)
    }

    fn index(&self, x: u32, y: u32) -> usize {
        (y as usize * self.width as usize + x as usize) * 3
    }
}

/// Where the horizontal field of view came from, reported in run.json.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FovSource {
    CommandLine,
    #[serde(rename = "exif_35mm_focal_length")]
    Exif35mmFocalLength,
    Default,
}

impl std::fmt::Display for FovSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::CommandLine => "--fov",
            Self::Exif35mmFocalLength => "from the EXIF 35 mm focal length",
            Self::Default => "the default",
        })
    }
}

#[derive(Clone, Debug)]
pub struct Photo {
    pub path: PathBuf,
    pub image: SrgbImage,
    pub hfov_deg: f64,
    pub fov_source: FovSource,
}

impl Photo {
    /// Loads a photo; `fov_override` (degrees) wins over the photo's metadata.
    pub fn load(path: &Path, fov_override: Option<f64>) -> Result<Self, PhotoError> {
        if let Some(fov) = fov_override {
            check_fov(fov)?;
        }
        let bytes = read(path)?;
        let image = SrgbImage::from_rgb8(&decode_rgb8(path, &bytes)?);
        let (hfov_deg, fov_source) = match fov_override {
            Some(fov) => (fov, FovSource::CommandLine),
            None => match exif_hfov(&bytes, image.width(), image.height()) {
                Some(fov) => (fov, FovSource::Exif35mmFocalLength),
                None => (DEFAULT_HFOV_DEG, FovSource::Default),
            },
        };
        log::info!(
            "photo {}: {}x{}, horizontal FOV {hfov_deg:.1}° ({fov_source})",
            path.display(),
            image.width(),
            image.height()
        );
        Ok(Self {
            path: path.into(),
            image,
            hfov_deg,
            fov_source,
        })
    }
}

/// The width and height of a photo as its header claims them, turned upright by its
/// EXIF orientation, without decoding its pixels (and without opening anything but a
/// regular file); `None` when the header cannot be read, which loading the photo then
/// reports.
pub fn header_size(path: &Path) -> Option<(u32, u32)> {
    use image::metadata::Orientation;
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
    let mut reader = ImageReader::open(path).ok()?.with_guessed_format().ok()?;
    reader.limits(limits::image_limits(u32::MAX));
    let mut decoder = reader.into_decoder().ok()?;
    let (w, h) = decoder.dimensions();
    let turned = matches!(
        decoder.orientation(),
        Ok(Orientation::Rotate90
            | Orientation::Rotate270
            | Orientation::Rotate90FlipH
            | Orientation::Rotate270FlipH)
    );
    Some(if turned { (h, w) } else { (w, h) })
}

/// Decodes an 8-bit RGB image within the size limits, turned upright by its EXIF
/// orientation.
pub fn load_rgb8(path: &Path) -> Result<RgbImage, PhotoError> {
    decode_rgb8(path, &read(path)?)
}

/// [`load_rgb8`] on a photo's bytes; `path` names it in errors and gives the format
/// when the content does not.
pub fn decode_rgb8(path: &Path, bytes: &[u8]) -> Result<RgbImage, PhotoError> {
    let (mut decoded, orientation) = decode(path, bytes)?;
    decoded.apply_orientation(orientation);
    if decoded.width() == 0 || decoded.height() == 0 {
        return Err(PhotoError::Empty { path: path.into() });
    }
    Ok(decoded.to_rgb8())
}

fn check_fov(fov: f64) -> Result<(), PhotoError> {
    if fov.is_finite() && fov > 0.0 && fov < 180.0 {
        Ok(())
    } else {
        Err(PhotoError::BadFov(fov))
    }
}

fn read(path: &Path) -> Result<Vec<u8>, PhotoError> {
    limits::read_input(path).map_err(|e| match e {
        ReadError::Io(source) => PhotoError::Io {
            path: path.into(),
            source,
        },
        ReadError::TooLarge(source) => PhotoError::TooLarge {
            path: path.into(),
            source,
        },
    })
}

fn decode(
    path: &Path,
    bytes: &[u8],
) -> Result<(DynamicImage, image::metadata::Orientation), PhotoError> {
    let decode_err = |source| PhotoError::Decode {
        path: path.into(),
        source,
    };
    if bytes.is_empty() {
        return Err(PhotoError::EmptyFile { path: path.into() });
    }
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|source| PhotoError::Io {
            path: path.into(),
            source,
        })?;
    if reader.format().is_none() {
        if let Ok(format) = ImageFormat::from_path(path) {
            reader.set_format(format);
        }
    }
    // Sides are checked below, with a message that gives them; the limit left here holds
    // the decoders' own buffers to the input budget.
    reader.limits(limits::image_limits(u32::MAX));
    let jpeg = reader.format() == Some(ImageFormat::Jpeg);
    let mut decoder = reader.into_decoder().map_err(decode_err)?;
    check_size(path, decoder.dimensions(), decoder.total_bytes())?;
    let orientation = decoder
        .orientation()
        .unwrap_or(image::metadata::Orientation::NoTransforms);
    let image = DynamicImage::from_decoder(decoder).map_err(decode_err)?;
    // Checked after decoding, so that garbage gets the decoder's own message.
    if jpeg {
        jpeg_complete(bytes).map_err(|detail| PhotoError::Truncated {
            path: path.into(),
            len: bytes.len(),
            detail,
        })?;
    }
    Ok((image, orientation))
}

/// Whether a JPEG's segments and scans run to its end-of-image marker. The JPEG
/// decoder fills whatever a cut-off file lacks with grey and reports success, so a photo
/// copied while still being written would otherwise convert into a half-grey frame.
/// Walks the marker segments by their lengths (so thumbnails inside APP segments do
/// not count) and the entropy-coded data of each scan to the next marker.
pub fn jpeg_complete(bytes: &[u8]) -> Result<(), &'static str> {
    const ENDS: &str = "the JPEG data ends before its end-of-image marker";
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return Ok(());
    }
    let mut i = 2;
    loop {
        // A marker: 0xFF (fill bytes may repeat it), then its code; stray bytes before
        // it are skipped, as libjpeg does.
        match bytes[i.min(bytes.len())..].iter().position(|&b| b == 0xFF) {
            Some(k) => i += k,
            None => return Err(ENDS),
        }
        while bytes.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        let Some(&code) = bytes.get(i + 1) else {
            return Err(ENDS);
        };
        i += 2;
        match code {
            0xD9 => return Ok(()),
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let len = match (bytes.get(i), bytes.get(i + 1)) {
            (Some(&hi), Some(&lo)) => usize::from(u16::from_be_bytes([hi, lo])),
            _ => return Err(ENDS),
        };
        if len < 2 {
            return Err("a JPEG segment has an impossible length");
        }
        i += len;
        if i > bytes.len() {
            return Err(ENDS);
        }
        if code == 0xDA {
            // Entropy-coded data: up to the next marker that is not a stuffed 0xFF00 or
            // a restart marker.
            loop {
                match bytes[i..].iter().position(|&b| b == 0xFF) {
                    None => return Err(ENDS),
                    Some(k) => i += k,
                }
                match bytes.get(i + 1) {
                    None => return Err(ENDS),
                    Some(0x00 | 0xD0..=0xD7 | 0xFF) => i += 1,
                    Some(_) => break,
                }
            }
        }
    }
}

/// Refuses a photo by its header before the decoder allocates its pixels (`image` does
/// not hold that buffer to the limits).
fn check_size(path: &Path, (width, height): (u32, u32), decoded: u64) -> Result<(), PhotoError> {
    if width > MAX_PHOTO_SIDE || height > MAX_PHOTO_SIDE {
        return Err(PhotoError::Size {
            path: path.into(),
            width,
            height,
        });
    }
    let pixels = u64::from(width) * u64::from(height);
    let needed = decoded.saturating_add(pixels * WORKING_BYTES_PER_PIXEL);
    limits::check_alloc(format!("a {width}x{height} photo"), needed, 1).map_err(|source| {
        PhotoError::TooLarge {
            path: path.into(),
            source,
        }
    })
}

/// Horizontal FOV from the EXIF 35 mm-equivalent focal length. The equivalence is
/// defined on the diagonal, so the horizontal angle follows from the image's own aspect
/// (portrait photos get the narrow angle).
pub fn exif_hfov(bytes: &[u8], width: u32, height: u32) -> Option<f64> {
    let exif = exif::Reader::new()
        .read_from_container(&mut Cursor::new(bytes))
        .ok()?;
    let field = exif.get_field(exif::Tag::FocalLengthIn35mmFilm, exif::In::PRIMARY)?;
    let focal_mm = f64::from(field.value.get_uint(0)?);
    hfov_from_35mm_focal(focal_mm, width, height)
}

/// Horizontal FOV (degrees) of an image of `width`×`height` pixels taken with a lens of
/// the given 35 mm-equivalent focal length; `None` for a zero (unknown) focal length.
pub fn hfov_from_35mm_focal(focal_mm: f64, width: u32, height: u32) -> Option<f64> {
    if focal_mm <= 0.0 || width == 0 || height == 0 {
        return None;
    }
    let (w, h) = (f64::from(width), f64::from(height));
    let half_diag_tan = FULL_FRAME_DIAGONAL_MM / (2.0 * focal_mm);
    let half_width_tan = half_diag_tan * w / w.hypot(h);
    Some(2.0 * half_width_tan.atan().to_degrees())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn to_rgb8_rounds_exactly_as_f32_round_does() {
        // Every value whose 255-multiple lies within 64 ulps of a half level, where a
        // shortcut through f32 addition would round the other way, and the extremes.
        let mut values = vec![-1.0, 0.0, 1.0, 2.0, f32::NAN, f32::INFINITY, 1e-30];
        for k in 0..256 {
            let centre = (k as f32 + 0.5) / 255.0;
            let mut v = centre;
            for _ in 0..64 {
                v = f32::from_bits(v.to_bits() - 1);
            }
            for _ in 0..129 {
                values.push(v);
                v = f32::from_bits(v.to_bits() + 1);
            }
        }
        values.truncate(values.len() / 3 * 3);
        let width = (values.len() / 3) as u32;
        let image =
            SrgbImage::from_rgb32f(Rgb32FImage::from_raw(width, 1, values.clone()).unwrap());
        let got = image.to_rgb8().into_raw();
        for (v, g) in values.iter().zip(got) {
            assert_eq!(g, (v.clamp(0.0, 1.0) * 255.0).round() as u8, "{v:e}");
        }
    }

    #[test]
    fn full_frame_landscape_matches_classic_angles() {
        // A 50 mm lens on a 36×24 frame covers 39.6° horizontally.
        let fov = hfov_from_35mm_focal(50.0, 3600, 2400).unwrap();
        assert!((fov - 39.6).abs() < 0.1, "{fov}");
    }

    #[test]
    fn portrait_gets_narrower_horizontal_angle() {
        let landscape = hfov_from_35mm_focal(28.0, 4032, 3024).unwrap();
        let portrait = hfov_from_35mm_focal(28.0, 3024, 4032).unwrap();
        assert!(portrait < landscape);
        assert!((portrait - 49.7).abs() < 0.2, "{portrait}");
    }

    #[test]
    fn unknown_focal_length_gives_none() {
        assert_eq!(hfov_from_35mm_focal(0.0, 10, 10), None);
    }

    /// A valid PNG whose header claims `width`×`height` pixels.
    fn png_claiming(width: u32, height: u32) -> Vec<u8> {
        let mut png = Vec::new();
        RgbImage::new(1, 1)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        // Signature (8), IHDR length (4), "IHDR" (4), then width and height.
        png[16..20].copy_from_slice(&width.to_be_bytes());
        png[20..24].copy_from_slice(&height.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        png
    }

    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    #[test]
    fn absurd_dimensions_are_refused_before_decoding() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.png");
        std::fs::write(&path, png_claiming(100_000, 100_000)).unwrap();
        let err = Photo::load(&path, None).unwrap_err();
        assert!(matches!(err, PhotoError::Size { .. }), "{err}");
        assert!(err.to_string().contains("huge.png"), "{err}");
        assert!(err.to_string().contains("100000x100000"), "{err}");
        // Within the side limit, the memory budget refuses it (16000² px at 15 B/px
        // is 3.6 GiB, beyond a quarter of the default ceiling).
        std::fs::write(&path, png_claiming(16_000, 16_000)).unwrap();
        let err = Photo::load(&path, None).unwrap_err();
        assert!(matches!(err, PhotoError::TooLarge { .. }), "{err}");
        assert!(err.to_string().contains("--max-memory"), "{err}");
        // The patched file is otherwise valid: with a true size it decodes.
        std::fs::write(&path, png_claiming(1, 1)).unwrap();
        assert!(Photo::load(&path, None).is_ok());
    }

    fn encoded(format: image::ImageFormat) -> Vec<u8> {
        let img = RgbImage::from_fn(96, 64, |x, y| {
            image::Rgb([x as u8 * 2, y as u8 * 3, ((x * 7 + y * 13) % 256) as u8])
        });
        let mut bytes = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut bytes), format)
            .unwrap();
        bytes
    }

    #[test]
    fn a_jpeg_cut_anywhere_is_refused_as_truncated() {
        let jpeg = encoded(image::ImageFormat::Jpeg);
        assert_eq!(jpeg_complete(&jpeg), Ok(()));
        // Bytes after the end-of-image marker (phone trailers) are fine.
        let mut trailer = jpeg.clone();
        trailer.extend_from_slice(b"SAMSUNG TRAILER \xff\xd8");
        assert_eq!(jpeg_complete(&trailer), Ok(()));
        for cut in 2..jpeg.len() - 1 {
            assert!(jpeg_complete(&jpeg[..cut]).is_err(), "cut at {cut}");
            let err = decode_rgb8(Path::new("half.jpg"), &jpeg[..cut]).unwrap_err();
            let text = err.to_string();
            assert!(
                text.contains("half.jpg")
                    && (text.contains("truncated") || text.contains("decode")),
                "cut at {cut}: {text}"
            );
        }
        let half = decode_rgb8(Path::new("half.jpg"), &jpeg[..jpeg.len() / 2]).unwrap_err();
        assert!(matches!(half, PhotoError::Truncated { .. }), "{half}");
    }

    #[test]
    fn a_png_cut_in_its_pixels_is_refused() {
        let png = encoded(image::ImageFormat::Png);
        assert!(decode_rgb8(Path::new("p.png"), &png).is_ok());
        // Cut anywhere before the end of the image data (IEND, 12 bytes, may go).
        for cut in 1..png.len() - 12 {
            let err = decode_rgb8(Path::new("p.png"), &png[..cut]);
            assert!(err.is_err(), "a PNG cut at {cut} of {} decoded", png.len());
        }
    }

    #[test]
    fn rgb8_roundtrip_is_exact() {
        let img = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 50, y as u8 * 80, 7]));
        assert_eq!(SrgbImage::from_rgb8(&img).to_rgb8(), img);
    }
}
