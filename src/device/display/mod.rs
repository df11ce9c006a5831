//! Where live frames go: a [`FrameSink`] shows one woven panel frame at a time, on a
//! Linux framebuffer ([`fb`]) or, headless, as numbered PNG files ([`PngSink`]).

pub mod fb;

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::RgbImage;

pub use fb::{Channel, FbGeometry, FramebufferSink};

#[derive(Debug, thiserror::Error)]
pub enum DisplayError {
    #[error("cannot write frame {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot encode frame {path}: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("framebuffer {path}: {source}")]
    Device {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("framebuffer {path}: {reason}")]
    Unsupported { path: PathBuf, reason: String },
    #[error("--display {spec:?}: {reason}")]
    BadSpec { spec: String, reason: String },
}

/// A place frames are shown.
pub trait FrameSink {
    /// What the sink is and what it found (device geometry, pixel format), for logs.
    fn describe(&self) -> String;
    fn show(&mut self, frame: &RgbImage) -> Result<(), DisplayError>;
}

/// Headless output: each frame becomes `frame_NNNNNN.png` in a directory, written under a
/// temporary name and renamed, so a reader never sees a partial PNG.
pub struct PngSink {
    dir: PathBuf,
    next: u64,
}

impl PngSink {
    pub fn new(dir: &Path) -> Result<Self, DisplayError> {
        std::fs::create_dir_all(dir).map_err(|source| DisplayError::Write {
            path: dir.into(),
            source,
        })?;
        Ok(Self {
            dir: dir.into(),
            next: 0,
        })
    }

    pub fn frame_path(&self, index: u64) -> PathBuf {
        self.dir.join(format!("frame_{index:06}.png"))
    }
}

impl FrameSink for PngSink {
    fn describe(&self) -> String {
        format!("PNG files in {}", self.dir.display())
    }

    fn show(&mut self, frame: &RgbImage) -> Result<(), DisplayError> {
        let path = self.frame_path(self.next);
        // Fast compression: this runs once per live frame, where the default level
        // costs more than weaving.
        let mut bytes = Vec::new();
        let encoder = PngEncoder::new_with_quality(
            Cursor::new(&mut bytes),
            CompressionType::Fast,
            FilterType::Sub,
        );
        frame
            .write_with_encoder(encoder)
            .map_err(|source| DisplayError::Encode {
                path: path.clone(),
                source,
            })?;
        crate::io::output::replace_file(&path, &bytes)
            .map_err(|source| DisplayError::Write { path, source })?;
        self.next += 1;
        Ok(())
    }
}

/// Parses `--display`: `none` (PNG files in `png_dir`), `png:DIR`, `fb:DEVICE`, or
/// `fb:FILE:WIDTHxHEIGHT:FORMAT[:STRIDE]` for a regular file standing in for a
/// framebuffer (FORMAT `xrgb8888`, `rgb565` or `rgb888`; STRIDE in bytes).
pub fn open_sink(spec: &str, png_dir: &Path) -> Result<Box<dyn FrameSink>, DisplayError> {
    if spec == "none" {
        return Ok(Box::new(PngSink::new(png_dir)?));
    }
    if let Some(dir) = spec.strip_prefix("png:") {
        return Ok(Box::new(PngSink::new(Path::new(dir))?));
    }
    let Some(rest) = spec.strip_prefix("fb:") else {
        return Err(DisplayError::BadSpec {
            spec: spec.into(),
            reason: "use none, png:DIR or fb:DEVICE".into(),
        });
    };
    let mut parts = rest.splitn(2, ':');
    let path = Path::new(parts.next().unwrap_or_default());
    let sink = match parts.next() {
        Some(geometry) => {
            let geometry = FbGeometry::parse(geometry).map_err(|reason| DisplayError::BadSpec {
                spec: spec.into(),
                reason,
            })?;
            FramebufferSink::open_with_geometry(path, geometry)?
        }
        None => FramebufferSink::open(path)?,
    };
    Ok(Box::new(sink))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_sink_numbers_frames_and_leaves_no_temporaries() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = PngSink::new(dir.path()).unwrap();
        let mut frame = RgbImage::new(3, 2);
        frame.put_pixel(2, 1, image::Rgb([10, 20, 30]));
        sink.show(&frame).unwrap();
        sink.show(&frame).unwrap();
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["frame_000000.png", "frame_000001.png"]);
        let back = image::open(dir.path().join("frame_000001.png"))
            .unwrap()
            .into_rgb8();
        assert_eq!(back, frame);
    }

    #[test]
    fn bad_display_specs_are_explained() {
        let dir = tempfile::tempdir().unwrap();
        let err = open_sink("hdmi", dir.path()).err().unwrap().to_string();
        assert!(err.contains("use none, png:DIR or fb:DEVICE"), "{err}");
        let err = open_sink("fb:/nonexistent/fb9", dir.path())
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("/nonexistent/fb9"), "{err}");
    }
}
