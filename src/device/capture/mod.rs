//! Camera input: a [`FrameSource`] yields RGB frames with timestamps, from a V4L2 camera
//! (feature `camera`, `v4l2`) or from a file of recorded raw frames ([`file`](mod@file)), so the
//! live pipeline runs the same code in CI as on the device.

pub mod file;
pub mod live;
#[cfg(feature = "camera")]
pub mod v4l2;

use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

use image::codecs::jpeg::JpegDecoder;
use image::{DynamicImage, ImageDecoder, Limits, RgbImage};

/// Frames larger than this on either side are refused before any buffer is sized from
/// them: no UVC camera streams wider than 8K.
pub const MAX_FRAME_SIDE: u32 = 8192;

/// An MJPEG frame is a compressed image; a larger one is corrupt or hostile.
pub const MAX_MJPEG_BYTES: usize = 32 << 20;

#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The device stopped existing (unplugged, driver unbound); retrying will not help.
    #[error("camera {device} is gone: {source}")]
    DeviceGone {
        device: String,
        source: std::io::Error,
    },
    #[error("cannot use camera {device}: {source}")]
    Device {
        device: String,
        source: std::io::Error,
    },
    #[error("camera {device}: {reason}")]
    Unsupported { device: String, reason: String },
    /// One frame's bytes are not a valid image of the stream's format.
    #[error("{origin}: frame {index}: {reason}")]
    BadFrame {
        origin: String,
        index: u64,
        reason: String,
    },
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The recording's header or framing is broken.
    #[error("{path}: not a usable frame recording: {reason}")]
    BadRecording { path: PathBuf, reason: String },
    #[error(
        "{device}: this build has no camera support; rebuild with `--features camera` \
         (needs libclang, e.g. `apt-get install libclang-dev`)"
    )]
    NoCameraSupport { device: String },
}

impl CaptureError {
    /// Whether the source can never deliver another frame (as opposed to one bad frame).
    pub fn is_fatal(&self) -> bool {
        !matches!(self, CaptureError::BadFrame { .. })
    }
}

/// Raw pixel formats the runtime decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// Packed 4:2:2 Y'CbCr, bytes Y0 U Y1 V per two pixels (V4L2 `YUYV`).
    Yuyv,
    /// Motion JPEG: each frame a complete JPEG image (V4L2 `MJPG`).
    Mjpeg,
}

impl PixelFormat {
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }

    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        match &code {
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"MJPG" => Some(PixelFormat::Mjpeg),
            _ => None,
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PixelFormat::Yuyv => "YUYV",
            PixelFormat::Mjpeg => "MJPEG",
        })
    }
}

impl std::str::FromStr for PixelFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "yuyv" => Ok(PixelFormat::Yuyv),
            "mjpeg" | "mjpg" => Ok(PixelFormat::Mjpeg),
            _ => Err(format!("unknown pixel format {s:?}; use yuyv or mjpeg")),
        }
    }
}

/// One decoded camera frame.
#[derive(Clone, Debug)]
pub struct Frame {
    pub image: RgbImage,
    /// Capture time relative to the stream's first frame.
    pub timestamp: Duration,
    /// Position in the stream, counting frames the source skipped.
    pub sequence: u64,
    /// Time spent decoding the raw bytes into `image`.
    pub decode_time: Duration,
}

/// Anything that produces camera frames. `next_frame` returns the freshest frame the
/// source has, so a slow consumer skips frames instead of falling behind; `Ok(None)` is
/// the end of a finite stream.
pub trait FrameSource: Send {
    /// What this source is, for logs: device or file, format and size.
    fn describe(&self) -> String;
    fn size(&self) -> (u32, u32);
    fn next_frame(&mut self) -> Result<Option<Frame>, CaptureError>;
    /// Frames skipped so far because a fresher one was available.
    fn dropped(&self) -> u64 {
        0
    }
    /// Whether frames arrive in real time (a camera, a paced replay), so a slow consumer
    /// must skip some; otherwise the consumer sets the pace and sees every frame.
    fn realtime(&self) -> bool {
        true
    }
}

/// Checks a stream's declared size before buffers are sized from it.
pub fn check_frame_size(format: PixelFormat, width: u32, height: u32) -> Result<(), String> {
    if width == 0 || height == 0 || width > MAX_FRAME_SIDE || height > MAX_FRAME_SIDE {
        return Err(format!(
            "frame size {width}x{height} is outside 1..={MAX_FRAME_SIDE} per side"
        ));
    }
    if format == PixelFormat::Yuyv && width % 2 != 0 {
        return Err(format!("YUYV needs an even width, got {width}"));
    }
    Ok(())
}

/// Decodes one raw frame of `format` that should be `width`×`height`.
pub fn decode_frame(
    format: PixelFormat,
    width: u32,
    height: u32,
    bytes: &[u8],
) -> Result<RgbImage, String> {
    match format {
        PixelFormat::Yuyv => yuyv_to_rgb(width, height, bytes),
        PixelFormat::Mjpeg => decode_mjpeg(width, height, bytes),
    }
}

/// Converts packed YUYV with BT.601 coefficients and limited ("studio") range, the
/// encoding UVC cameras use: Y' in 16..235, Cb/Cr in 16..240 centred on 128.
pub fn yuyv_to_rgb(width: u32, height: u32, bytes: &[u8]) -> Result<RgbImage, String> {
    let expected = width as usize * height as usize * 2;
    if width % 2 != 0 {
        return Err(format!("YUYV needs an even width, got {width}"));
    }
    if bytes.len() < expected {
        return Err(format!(
            "YUYV frame has {} bytes, {width}x{height} needs {expected}",
            bytes.len()
        ));
    }
    let mut rgb = Vec::with_capacity(width as usize * height as usize * 3);
    for quad in bytes[..expected].chunks_exact(4) {
        let (y0, u, y1, v) = (quad[0], quad[1], quad[2], quad[3]);
        rgb.extend_from_slice(&ycbcr_to_rgb(y0, u, v));
        rgb.extend_from_slice(&ycbcr_to_rgb(y1, u, v));
    }
    Ok(RgbImage::from_raw(width, height, rgb).expect("buffer matches size"))
}

/// BT.601 limited range in 8.8 fixed point: R = 1.164(Y−16) + 1.596(Cr−128),
/// G = 1.164(Y−16) − 0.392(Cb−128) − 0.813(Cr−128), B = 1.164(Y−16) + 2.017(Cb−128),
/// the coefficients scaled by 256 and rounded.
pub fn ycbcr_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    let c = 298 * (i32::from(y) - 16);
    let d = i32::from(cb) - 128;
    let e = i32::from(cr) - 128;
    let clamp = |v: i32| ((v + 128) >> 8).clamp(0, 255) as u8;
    [
        clamp(c + 409 * e),
        clamp(c - 100 * d - 208 * e),
        clamp(c + 516 * d),
    ]
}

/// Decodes one MJPEG frame, refusing frames whose JPEG header disagrees with the
/// stream's size before the pixels are allocated.
pub fn decode_mjpeg(width: u32, height: u32, bytes: &[u8]) -> Result<RgbImage, String> {
    if bytes.len() > MAX_MJPEG_BYTES {
        return Err(format!(
            "MJPEG frame of {} bytes exceeds {MAX_MJPEG_BYTES}",
            bytes.len()
        ));
    }
    let mut decoder =
        JpegDecoder::new(std::io::Cursor::new(bytes)).map_err(|e| format!("bad JPEG: {e}"))?;
    let (w, h) = decoder.dimensions();
    if (w, h) != (width, height) {
        return Err(format!(
            "JPEG is {w}x{h} but the stream is {width}x{height}"
        ));
    }
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_FRAME_SIDE);
    limits.max_image_height = Some(MAX_FRAME_SIDE);
    decoder
        .set_limits(limits)
        .map_err(|e| format!("bad JPEG: {e}"))?;
    let image = DynamicImage::from_decoder(decoder).map_err(|e| format!("bad JPEG: {e}"))?;
    Ok(image.into_rgb8())
}

/// Opens `--camera`: a recording made by [`file::FrameWriter`] when the path is a regular
/// file, a V4L2 device otherwise.
pub fn open_source(
    camera: &std::path::Path,
    request: &CameraRequest,
) -> Result<Box<dyn FrameSource>, CaptureError> {
    if camera.is_file() {
        let source = file::FileSource::open(camera)?.paced(request.paced);
        return Ok(Box::new(source));
    }
    open_device(camera, request)
}

/// What the live command asks of a camera; the device grants the nearest it supports.
#[derive(Clone, Debug, Default)]
pub struct CameraRequest {
    pub format: Option<PixelFormat>,
    pub size: Option<(u32, u32)>,
    pub fps: Option<u32>,
    /// For recordings: deliver frames at their recorded times, skipping late ones.
    pub paced: bool,
}

#[cfg(feature = "camera")]
fn open_device(
    camera: &std::path::Path,
    request: &CameraRequest,
) -> Result<Box<dyn FrameSource>, CaptureError> {
    Ok(Box::new(v4l2::V4l2Source::open(camera, request)?))
}

#[cfg(not(feature = "camera"))]
fn open_device(
    camera: &std::path::Path,
    _request: &CameraRequest,
) -> Result<Box<dyn FrameSource>, CaptureError> {
    Err(no_camera_support(camera))
}

#[cfg(not(feature = "camera"))]
fn no_camera_support(camera: &std::path::Path) -> CaptureError {
    if camera.exists() {
        CaptureError::NoCameraSupport {
            device: camera.display().to_string(),
        }
    } else {
        CaptureError::Device {
            device: camera.display().to_string(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        }
    }
}

/// One pixel format a camera offers, with its frame sizes and rates.
#[derive(Clone, Debug)]
pub struct FormatInfo {
    pub fourcc: String,
    pub description: String,
    /// Frame sizes, each with the frame rates offered at it (empty when the device
    /// reports ranges rather than a list).
    pub sizes: Vec<(u32, u32, Vec<f64>)>,
    /// Whether this runtime can decode the format.
    pub supported: bool,
}

/// The formats `camera` offers (`--list-formats`); for a recording, its one format.
pub fn list_formats(camera: &std::path::Path) -> Result<Vec<FormatInfo>, CaptureError> {
    if camera.is_file() {
        let source = file::FileSource::open(camera)?;
        let (w, h) = source.size();
        return Ok(vec![FormatInfo {
            fourcc: String::from_utf8_lossy(&source.format().fourcc()).into_owned(),
            description: format!("recording {}", camera.display()),
            sizes: vec![(w, h, Vec::new())],
            supported: true,
        }]);
    }
    device_formats(camera)
}

#[cfg(feature = "camera")]
fn device_formats(camera: &std::path::Path) -> Result<Vec<FormatInfo>, CaptureError> {
    v4l2::list_formats(camera)
}

#[cfg(not(feature = "camera"))]
fn device_formats(camera: &std::path::Path) -> Result<Vec<FormatInfo>, CaptureError> {
    Err(no_camera_support(camera))
}

impl fmt::Display for FormatInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let note = if self.supported {
            ""
        } else {
            " (not decodable by reshader)"
        };
        writeln!(f, "{} {}{note}", self.fourcc, self.description)?;
        for (w, h, rates) in &self.sizes {
            let rates: Vec<String> = rates.iter().map(|r| format!("{r:.4}")).collect();
            if rates.is_empty() {
                writeln!(f, "  {w}x{h}")?;
            } else {
                writeln!(f, "  {w}x{h} @ {} fps", rates.join(", "))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bt601_limited_range_reference_colours() {
        assert_eq!(ycbcr_to_rgb(16, 128, 128), [0, 0, 0]);
        assert_eq!(ycbcr_to_rgb(235, 128, 128), [255, 255, 255]);
        // 75% grey: Y = 16 + 219·0.75 = 180.25 → 180 decodes to 1.164·164 = 190.9.
        assert_eq!(ycbcr_to_rgb(180, 128, 128), [191, 191, 191]);
        // Full red in BT.601 limited range is (Y, Cb, Cr) = (81, 90, 240).
        assert_eq!(ycbcr_to_rgb(81, 90, 240), [255, 0, 0]);
        // Full blue is (41, 240, 110).
        assert_eq!(ycbcr_to_rgb(41, 240, 110), [0, 0, 255]);
    }

    #[test]
    fn bt601_matches_the_float_formula_within_one_step() {
        // Y=120, Cb=100, Cr=150 by hand: C=104, D=−28, E=22.
        // R = 1.164·104 + 1.596·22 = 156.1; G = 121.06 + 10.97 − 17.89 = 114.1;
        // B = 121.06 − 56.48 = 64.6.
        let [r, g, b] = ycbcr_to_rgb(120, 100, 150);
        for (got, want) in [(r, 156.1), (g, 114.1), (b, 64.6)] {
            assert!((f64::from(got) - want).abs() <= 1.0, "{got} vs {want}");
        }
    }

    #[test]
    fn yuyv_shares_chroma_between_pixel_pairs() {
        // Two pixels: black then white with neutral chroma, then a red pair.
        let bytes = [16, 128, 235, 128, 81, 90, 81, 240];
        let image = yuyv_to_rgb(4, 1, &bytes).unwrap();
        assert_eq!(image.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(image.get_pixel(1, 0).0, [255, 255, 255]);
        assert_eq!(image.get_pixel(2, 0).0, [255, 0, 0]);
        assert_eq!(image.get_pixel(3, 0).0, [255, 0, 0]);
    }

    #[test]
    fn yuyv_short_buffer_and_odd_width_are_errors() {
        let err = yuyv_to_rgb(4, 2, &[0; 10]).unwrap_err();
        assert!(err.contains("needs 16"), "{err}");
        assert!(yuyv_to_rgb(3, 1, &[0; 6])
            .unwrap_err()
            .contains("even width"));
    }

    #[test]
    fn mjpeg_size_mismatch_and_garbage_are_errors() {
        let mut jpeg = Vec::new();
        RgbImage::new(8, 8)
            .write_to(
                &mut std::io::Cursor::new(&mut jpeg),
                image::ImageFormat::Jpeg,
            )
            .unwrap();
        assert!(decode_mjpeg(8, 8, &jpeg).is_ok());
        assert!(decode_mjpeg(16, 8, &jpeg).unwrap_err().contains("8x8"));
        assert!(decode_mjpeg(8, 8, b"not a jpeg")
            .unwrap_err()
            .contains("bad JPEG"));
    }

    #[test]
    fn pixel_format_names_round_trip() {
        for f in [PixelFormat::Yuyv, PixelFormat::Mjpeg] {
            assert_eq!(PixelFormat::from_fourcc(f.fourcc()), Some(f));
        }
        assert_eq!("mjpg".parse::<PixelFormat>(), Ok(PixelFormat::Mjpeg));
        assert!("nv12".parse::<PixelFormat>().is_err());
    }
}
