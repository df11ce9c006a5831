//! Depth files: reading .npy, 16-bit .png, .pfm and .exr into raw numbers, with the
//! memory ceiling checked before anything is decoded, and writing a map in any of them.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageBuffer, ImageDecoder, ImageFormat, Luma};

use super::{DepthError, DepthMap, RawMap, MAX_SIDE, PNG_UNITS_PER_VALUE};
use crate::io::limits::{self, ReadError};
use crate::io::npy;
use crate::io::output::{FileFormat, OutputError};
use crate::io::pfm;

impl DepthMap {
    /// Encodes the map in the format named by the extension of `path`: .npy (float32),
    /// .pfm, .exr (float, one channel named Z) or .png (16-bit, thousandths of a unit).
    pub fn encode(&self, path: &Path) -> Result<Vec<u8>, DepthError> {
        let all = [
            FileFormat::Npy,
            FileFormat::Pfm,
            FileFormat::Exr,
            FileFormat::Png,
        ];
        let format = FileFormat::require(path, &all)?;
        let encode_err = |source| {
            DepthError::Output(OutputError::Encode {
                path: path.into(),
                source,
            })
        };
        match format {
            FileFormat::Npy => Ok(npy::encode_f32(&[self.height, self.width], &self.data)),
            FileFormat::Pfm => Ok(pfm::encode(self.width, self.height, &self.data)),
            FileFormat::Exr => encode_exr(path, self),
            FileFormat::Png => {
                let clipped = self
                    .data
                    .iter()
                    .filter(|&&d| d / PNG_UNITS_PER_VALUE > f32::from(u16::MAX))
                    .count();
                if clipped > 0 {
                    log::warn!(
                        "{}: {clipped} depths exceed the 16-bit PNG range ({} units) and are clipped",
                        path.display(),
                        f32::from(u16::MAX) * PNG_UNITS_PER_VALUE
                    );
                }
                let values: Vec<u16> = self
                    .data
                    .iter()
                    .map(|&d| (d / PNG_UNITS_PER_VALUE).round().clamp(1.0, 65535.0) as u16)
                    .collect();
                let img: ImageBuffer<Luma<u16>, Vec<u16>> =
                    ImageBuffer::from_raw(self.width as u32, self.height as u32, values)
                        .expect("buffer matches size");
                let mut buf = Cursor::new(Vec::new());
                img.write_to(&mut buf, ImageFormat::Png)
                    .map_err(encode_err)?;
                Ok(buf.into_inner())
            }
        }
    }
}

/// Reads the numbers of a depth file without interpreting them.
pub fn read_raw(path: &Path) -> Result<RawMap, DepthError> {
    let bytes = limits::read_input(path).map_err(|e| match e {
        ReadError::Io(source) => DepthError::Io {
            path: path.into(),
            source,
        },
        ReadError::TooLarge(source) => DepthError::TooLarge {
            path: path.into(),
            source,
        },
    })?;
    parse_raw(path, &bytes)
}

/// [`read_raw`] on a file's bytes: `path` names the file in errors, and its extension
/// gives the format.
pub fn parse_raw(path: &Path, bytes: &[u8]) -> Result<RawMap, DepthError> {
    let raw = match FileFormat::from_path(path) {
        Some(FileFormat::Npy) => {
            let arr = npy::parse(bytes).map_err(|source| DepthError::Npy {
                path: path.into(),
                source,
            })?;
            RawMap {
                width: arr.cols,
                height: arr.rows,
                values: arr.data,
            }
        }
        Some(FileFormat::Pfm) => {
            let map = pfm::parse(bytes).map_err(|source| DepthError::Pfm {
                path: path.into(),
                source,
            })?;
            RawMap {
                width: map.width,
                height: map.height,
                values: map.data,
            }
        }
        Some(FileFormat::Png) => read_png16(path, bytes)?,
        Some(FileFormat::Exr) => read_exr(path, bytes)?,
        None => return Err(DepthError::Extension { path: path.into() }),
    };
    check_size(path, raw.width, raw.height, 0)?;
    Ok(raw)
}

/// Refuses a map by its size, before its values are allocated where the format allows:
/// `extra` is what the decoder needs besides the float values.
fn check_size(path: &Path, width: usize, height: usize, extra: u64) -> Result<(), DepthError> {
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(DepthError::Size {
            path: path.into(),
            width,
            height,
        });
    }
    let floats = (width * height) as u64 * 4;
    limits::check_alloc(
        format!("a {width}x{height} map"),
        floats.saturating_add(extra),
        1,
    )
    .map_err(|source| DepthError::TooLarge {
        path: path.into(),
        source,
    })
}

fn decode_image(
    path: &Path,
    bytes: &[u8],
    format: ImageFormat,
) -> Result<DynamicImage, DepthError> {
    let decode_err = |source| DepthError::Decode {
        path: path.into(),
        source,
    };
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    // Sides are checked below with a message that names them.
    reader.limits(limits::image_limits(u32::MAX));
    let decoder = reader.into_decoder().map_err(decode_err)?;
    let (width, height) = decoder.dimensions();
    check_size(path, width as usize, height as usize, decoder.total_bytes())?;
    DynamicImage::from_decoder(decoder).map_err(decode_err)
}

fn read_png16(path: &Path, bytes: &[u8]) -> Result<RawMap, DepthError> {
    let DynamicImage::ImageLuma16(img) = decode_image(path, bytes, ImageFormat::Png)? else {
        return Err(DepthError::Channels {
            path: path.into(),
            detail: "a PNG depth map must be 16-bit greyscale".into(),
        });
    };
    Ok(RawMap {
        width: img.width() as usize,
        height: img.height() as usize,
        values: img
            .as_raw()
            .iter()
            .map(|&v| f32::from(v) * PNG_UNITS_PER_VALUE)
            .collect(),
    })
}

/// Channels an EXR depth map is looked for in, in order; otherwise the first channel.
const EXR_DEPTH_CHANNELS: [&str; 5] = ["Z", "depth", "Y", "R", "V"];

/// EXR depth comes from the channel named Z (or depth, Y, R, V), else the first one:
/// depth EXRs are usually single-channel, which the image crate's RGB reader refuses.
fn read_exr(path: &Path, bytes: &[u8]) -> Result<RawMap, DepthError> {
    use exr::prelude::*;
    let exr_err = |source| DepthError::Exr {
        path: path.into(),
        source,
    };
    // The reader allocates every channel of a layer from its header's size: check them
    // all before reading.
    let meta =
        exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(exr_err)?;
    for header in meta.headers.iter().filter(|h| !h.deep) {
        let (w, h) = (header.layer_size.x(), header.layer_size.y());
        let samples = (w as u64).saturating_mul(h as u64);
        let stored = samples.saturating_mul(header.channels.bytes_per_pixel as u64);
        check_size(path, w, h, stored)?;
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(exr_err)?;
    let layer = image.layer_data;
    let channels = &layer.channel_data.list;
    let channel = EXR_DEPTH_CHANNELS
        .iter()
        .find_map(|name| channels.iter().find(|c| c.name.eq(name)))
        .or_else(|| channels.first())
        .ok_or_else(|| DepthError::Channels {
            path: path.into(),
            detail: "the EXR has no channels".into(),
        })?;
    let values = match &channel.sample_data {
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
    };
    Ok(RawMap {
        width: layer.size.x(),
        height: layer.size.y(),
        values,
    })
}

/// A single-channel ("Z") float EXR.
fn encode_exr(path: &Path, map: &DepthMap) -> Result<Vec<u8>, DepthError> {
    use exr::prelude::*;
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
        "Z",
        FlatSamples::F32(map.data.clone()),
    )]));
    let layer = Layer::new(
        (map.width, map.height),
        LayerAttributes::named("depth"),
        Encoding::FAST_LOSSLESS,
        channels,
    );
    let mut buf = Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut buf)
        .map_err(|source| DepthError::Exr {
            path: path.into(),
            source,
        })?;
    Ok(buf.into_inner())
}
