//! Depth that phone cameras store inside their JPEGs, in the two forms in use:
//!
//! - Google "GDepth" XMP: `GDepth:Data` holds the depth image (base64 PNG or JPEG, usually
//!   in the Extended XMP because it exceeds one 64 KB APP1 segment), with
//!   `GDepth:Format` (`RangeInverse` / `RangeLinear`), `GDepth:Near` and `GDepth:Far`.
//! - Android Dynamic Depth: the XMP's `Container:Directory` lists items; the primary image
//!   is the JPEG itself and the others are appended after it, each `Item:Length` bytes
//!   followed by `Item:Padding` bytes, ending at the end of the file. A camera's
//!   `DepthMap` (Format, Near, Far, ItemSemantic) names the item holding the depth image.
//!
//! Both encode normalised values `v` in [0, 1] (8- or 16-bit): RangeLinear gives
//! `depth = near + v (far − near)`, RangeInverse `depth = far·near / (far − v (far − near))`.
//! Everything read from the file is bounds-checked: a malformed file gives an error
//! naming the problem, never a panic or an unbounded allocation.

mod jpeg;
mod xml;

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{DynamicImage, ImageDecoder, ImageFormat};

use crate::depth::RawMap;
use xml::Element;

const NS_GDEPTH: &str = "http://ns.google.com/photos/1.0/depthmap/";
const NS_DD_DEPTHMAP: &str = "http://ns.google.com/photos/dd/1.0/depthmap/";
/// Dynamic Depth's item namespace, and the older GContainer one motion photos use.
const NS_ITEM: [&str; 2] = [
    "http://ns.google.com/photos/dd/1.0/item/",
    "http://ns.google.com/photos/1.0/container/item/",
];
/// Depth images larger than this on a side are refused before decoding.
const MAX_DEPTH_SIDE: u32 = 16_384;

#[derive(Debug, thiserror::Error)]
pub enum EmbeddedError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: embedded depth is unreadable: {problem}")]
    Malformed { path: PathBuf, problem: String },
    #[error("{path}: {source}")]
    TooLarge {
        path: PathBuf,
        source: crate::io::limits::TooLarge,
    },
    #[error("{path} carries no embedded depth (GDepth or Dynamic Depth)")]
    Missing { path: PathBuf },
    #[error("{path}: {problem}")]
    Unfit { path: PathBuf, problem: String },
}

/// Which of the two forms the depth came in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Container {
    GDepth,
    DynamicDepth,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum RangeFormat {
    RangeInverse,
    RangeLinear,
}

/// The names the metadata uses, for messages.
impl std::fmt::Display for Container {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::GDepth => "GDepth",
            Self::DynamicDepth => "Dynamic Depth",
        })
    }
}

impl std::fmt::Display for RangeFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::RangeInverse => "RangeInverse",
            Self::RangeLinear => "RangeLinear",
        })
    }
}

/// Depth found in a photo, in the units its metadata gives (metres on phones).
#[derive(Clone, Debug, PartialEq)]
pub struct EmbeddedDepth {
    pub container: Container,
    pub format: RangeFormat,
    pub near: f32,
    pub far: f32,
    pub units: Option<String>,
    pub mime: String,
    /// Depth (not disparity) per pixel of the depth image, as stored (no EXIF rotation).
    pub map: RawMap,
    /// The photo's EXIF orientation (1..=8), which the depth image shares.
    pub orientation: u32,
}

/// The embedded depth of the JPEG at `path`: `Ok(None)` when it carries none (or is not a
/// JPEG), an error when it claims depth that cannot be read.
pub fn read(path: &Path) -> Result<Option<EmbeddedDepth>, EmbeddedError> {
    let bytes = crate::io::limits::read_input(path).map_err(|e| match e {
        crate::io::limits::ReadError::Io(source) => EmbeddedError::Io {
            path: path.into(),
            source,
        },
        crate::io::limits::ReadError::TooLarge(source) => EmbeddedError::TooLarge {
            path: path.into(),
            source,
        },
    })?;
    parse(&bytes).map_err(|problem| EmbeddedError::Malformed {
        path: path.into(),
        problem,
    })
}

/// [`read`] on the file's bytes; errors are the problem without the file name.
pub fn parse(bytes: &[u8]) -> Result<Option<EmbeddedDepth>, String> {
    if !jpeg::is_jpeg(bytes) {
        return Ok(None);
    }
    let layout = jpeg::scan(bytes)?;
    let Some(xmp) = layout.standard_xmp else {
        return Ok(None);
    };
    let standard = xml::parse(&xmp).map_err(|e| format!("XMP: {e}"))?;
    let extended = jpeg::extended_xmp(&layout.extended, &standard)?
        .map(|packet| xml::parse(&packet).map_err(|e| format!("Extended XMP: {e}")))
        .transpose()?;
    let trees: Vec<&Element> = std::iter::once(&standard)
        .chain(extended.as_ref())
        .collect();
    let found = match dynamic_depth(bytes, layout.primary_end, &trees)? {
        Some(depth) => Some(depth),
        None => gdepth(&trees)?,
    };
    Ok(found.map(|d| EmbeddedDepth {
        orientation: exif_orientation(bytes),
        ..d
    }))
}

/// The EXIF orientation tag (1..=8) of a JPEG; 1 when absent or invalid.
fn exif_orientation(bytes: &[u8]) -> u32 {
    exif::Reader::new()
        .read_from_container(&mut Cursor::new(bytes))
        .ok()
        .and_then(|e| {
            e.get_field(exif::Tag::Orientation, exif::In::PRIMARY)
                .and_then(|f| f.value.get_uint(0))
        })
        .filter(|o| (1..=8).contains(o))
        .unwrap_or(1)
}

fn gdepth(trees: &[&Element]) -> Result<Option<EmbeddedDepth>, String> {
    let get = |local: &str| trees.iter().find_map(|t| t.find_prop(&[NS_GDEPTH], local));
    let Some(data) = get("Data") else {
        if get("Format").is_some() {
            return Err(
                "GDepth metadata without GDepth:Data (is the Extended XMP missing?)".into(),
            );
        }
        return Ok(None);
    };
    let range = Range::parse("GDepth", &get)?;
    let mime = get("Mime").unwrap_or_else(|| "image/png".into());
    let encoded = base64_decode(&data).map_err(|e| format!("GDepth:Data is not base64: {e}"))?;
    let map = range.decode_image(&encoded, &mime, "GDepth:Data")?;
    Ok(Some(range.into_depth(Container::GDepth, mime, map)))
}

/// Near, far, format and units, checked.
struct Range {
    format: RangeFormat,
    near: f32,
    far: f32,
    units: Option<String>,
}

impl Range {
    fn parse(prefix: &str, get: &dyn Fn(&str) -> Option<String>) -> Result<Self, String> {
        let format = match get("Format").as_deref() {
            Some("RangeInverse") => RangeFormat::RangeInverse,
            Some("RangeLinear") => RangeFormat::RangeLinear,
            Some(other) => {
                return Err(format!(
                    "{prefix}:Format is {other:?}; expected RangeInverse or RangeLinear"
                ))
            }
            None => return Err(format!("{prefix}:Format is missing")),
        };
        let number = |name: &str| -> Result<f32, String> {
            let text = get(name).ok_or_else(|| format!("{prefix}:{name} is missing"))?;
            text.trim()
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| format!("{prefix}:{name} is {text:?}; expected a positive number"))
        };
        let (near, far) = (number("Near")?, number("Far")?);
        if far <= near {
            return Err(format!(
                "{prefix}:Far ({far}) must be greater than {prefix}:Near ({near})"
            ));
        }
        Ok(Self {
            format,
            near,
            far,
            units: get("Units"),
        })
    }

    /// Normalised values of the depth image, row-major.
    fn decode_image(&self, bytes: &[u8], mime: &str, what: &str) -> Result<RawMap, String> {
        let format = match mime {
            "image/png" => ImageFormat::Png,
            "image/jpeg" => ImageFormat::Jpeg,
            other => {
                return Err(format!(
                    "{what} has MIME type {other:?}; expected image/png or image/jpeg"
                ))
            }
        };
        let decode_err = |e| format!("{what}: cannot decode the depth image: {e}");
        let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
        reader.limits(crate::io::limits::image_limits(MAX_DEPTH_SIDE));
        let decoder = reader.into_decoder().map_err(decode_err)?;
        let (w, h) = decoder.dimensions();
        // The decoded image, a 16-bit grey copy and the float values.
        let pixels = u64::from(w) * u64::from(h);
        let needed = decoder.total_bytes().saturating_add(pixels * (2 + 4));
        crate::io::limits::check_alloc(format!("{what}: a {w}x{h} depth image"), needed, 1)
            .map_err(|e| e.to_string())?;
        let img = DynamicImage::from_decoder(decoder).map_err(decode_err)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let values: Vec<f32> = match img {
            DynamicImage::ImageLuma16(g) => {
                g.as_raw().iter().map(|&v| f32::from(v) / 65535.0).collect()
            }
            DynamicImage::ImageLumaA16(_)
            | DynamicImage::ImageRgb16(_)
            | DynamicImage::ImageRgba16(_) => img
                .to_luma16()
                .as_raw()
                .iter()
                .map(|&v| f32::from(v) / 65535.0)
                .collect(),
            other => other
                .to_luma8()
                .as_raw()
                .iter()
                .map(|&v| f32::from(v) / 255.0)
                .collect(),
        };
        Ok(RawMap {
            width,
            height,
            values,
        })
    }

    fn depth(&self, v: f32) -> f32 {
        let (n, f) = (self.near, self.far);
        match self.format {
            RangeFormat::RangeLinear => n + v * (f - n),
            RangeFormat::RangeInverse => f * n / (f - v * (f - n)),
        }
    }

    fn into_depth(self, container: Container, mime: String, mut map: RawMap) -> EmbeddedDepth {
        for v in &mut map.values {
            *v = self.depth(*v);
        }
        EmbeddedDepth {
            container,
            format: self.format,
            near: self.near,
            far: self.far,
            units: self.units,
            mime,
            map,
            orientation: 1,
        }
    }
}

/// One entry of a Dynamic Depth directory.
struct Item {
    mime: String,
    semantic: String,
    length: usize,
    padding: usize,
}

fn dynamic_depth(
    bytes: &[u8],
    primary_end: usize,
    trees: &[&Element],
) -> Result<Option<EmbeddedDepth>, String> {
    let Some(depth_map) = trees
        .iter()
        .find_map(|t| t.find(&|e| e.prop(&[NS_DD_DEPTHMAP], "Format").is_some()))
    else {
        return Ok(None);
    };
    let get = |local: &str| depth_map.prop(&[NS_DD_DEPTHMAP], local);
    let range = Range::parse("DepthMap", &get)?;
    let semantic = get("ItemSemantic").unwrap_or_else(|| "Depth".into());
    let items = directory(trees)?;
    let offsets = item_offsets(&items, bytes.len(), primary_end)?;
    let (index, item) = items
        .iter()
        .enumerate()
        .find(|(_, it)| it.semantic == semantic)
        .ok_or_else(|| {
            format!("Container:Directory has no item with Item:Semantic {semantic:?}")
        })?;
    let start = offsets[index].ok_or("the depth item is the primary image")?;
    let data = &bytes[start..start + item.length];
    let map = range.decode_image(data, &item.mime, "the depth item")?;
    Ok(Some(range.into_depth(
        Container::DynamicDepth,
        item.mime.clone(),
        map,
    )))
}

/// The directory's items in document order: any element carrying `Item:Mime`.
fn directory(trees: &[&Element]) -> Result<Vec<Item>, String> {
    let mut items = Vec::new();
    for tree in trees {
        tree.visit(&mut |e| {
            if let Some(mime) = e.prop(&NS_ITEM, "Mime") {
                items.push((
                    mime,
                    e.prop(&NS_ITEM, "Semantic"),
                    e.prop(&NS_ITEM, "Length"),
                    e.prop(&NS_ITEM, "Padding"),
                ));
            }
        });
    }
    if items.is_empty() {
        return Err("DepthMap metadata but no Container:Directory items".into());
    }
    let count = |v: Option<String>, what: &str, i: usize| -> Result<usize, String> {
        match v {
            None => Ok(0),
            Some(t) => t
                .trim()
                .parse::<usize>()
                .map_err(|_| format!("item {i}: Item:{what} is {t:?}; expected a byte count")),
        }
    };
    items
        .into_iter()
        .enumerate()
        .map(|(i, (mime, semantic, length, padding))| {
            Ok(Item {
                mime,
                semantic: semantic.ok_or_else(|| format!("item {i} has no Item:Semantic"))?,
                length: count(length, "Length", i)?,
                padding: count(padding, "Padding", i)?,
            })
        })
        .collect()
}

/// Where each secondary item starts: they fill the end of the file, in order, so they are
/// laid out backwards from its end; they must not reach into the primary image.
fn item_offsets(
    items: &[Item],
    file_len: usize,
    primary_end: usize,
) -> Result<Vec<Option<usize>>, String> {
    let mut tail = 0usize;
    for (i, item) in items.iter().enumerate().skip(1) {
        if item.length == 0 {
            return Err(format!("item {i} ({}) has no Item:Length", item.semantic));
        }
        tail = tail
            .checked_add(item.length)
            .and_then(|t| t.checked_add(item.padding))
            .filter(|&t| t <= file_len.saturating_sub(primary_end))
            .ok_or_else(|| {
                format!(
                    "the directory's items need more bytes than the {} after the primary image",
                    file_len.saturating_sub(primary_end)
                )
            })?;
    }
    let mut at = file_len - tail;
    let mut offsets = vec![None];
    for item in items.iter().skip(1) {
        offsets.push(Some(at));
        at += item.length + item.padding;
    }
    Ok(offsets)
}

/// Standard base64 (RFC 4648), whitespace ignored, padding optional.
pub fn base64_decode(text: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    let mut padding = 0;
    for (i, c) in text.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => {
                padding += 1;
                continue;
            }
            b' ' | b'\t' | b'\r' | b'\n' => continue,
            _ => return Err(format!("byte {c:#04x} at {i} is not a base64 character")),
        };
        if padding > 0 {
            return Err(format!("data after '=' padding at {i}"));
        }
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits >= 6 {
        return Err("truncated (a lone trailing character)".into());
    }
    Ok(out)
}

/// Turns a map stored in sensor orientation upright, as the photo is by its EXIF
/// orientation tag (1..=8).
pub fn apply_orientation(map: &RawMap, orientation: u32) -> RawMap {
    let (w, h) = (map.width, map.height);
    let swap = (5..=8).contains(&orientation);
    let (ow, oh) = if swap { (h, w) } else { (w, h) };
    let mut values = Vec::with_capacity(w * h);
    for y in 0..oh {
        for x in 0..ow {
            let (sx, sy) = match orientation {
                2 => (w - 1 - x, y),
                3 => (w - 1 - x, h - 1 - y),
                4 => (x, h - 1 - y),
                5 => (y, x),
                6 => (y, h - 1 - x),
                7 => (w - 1 - y, h - 1 - x),
                8 => (w - 1 - y, x),
                _ => (x, y),
            };
            values.push(map.values[sy * w + sx]);
        }
    }
    RawMap {
        width: ow,
        height: oh,
        values,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_decodes_with_and_without_padding() {
        assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64_decode("aGVs\nbG8").unwrap(), b"hello");
        assert!(base64_decode("aGV*bG8=").unwrap_err().contains("0x2a"));
        assert!(base64_decode("aGVsb").is_err());
    }

    #[test]
    fn orientation_six_rotates_clockwise() {
        // 2x1 [a b] stored sideways; tag 6 means "rotate 90° clockwise to view".
        let map = RawMap {
            width: 2,
            height: 1,
            values: vec![1.0, 2.0],
        };
        let up = apply_orientation(&map, 6);
        assert_eq!((up.width, up.height), (1, 2));
        assert_eq!(up.values, vec![1.0, 2.0]);
        let up = apply_orientation(&map, 8);
        assert_eq!(up.values, vec![2.0, 1.0]);
    }

    #[test]
    fn range_formulas_hit_near_and_far() {
        for format in [RangeFormat::RangeInverse, RangeFormat::RangeLinear] {
            let r = Range {
                format,
                near: 0.5,
                far: 4.0,
                units: None,
            };
            assert!((r.depth(0.0) - 0.5).abs() < 1e-6);
            assert!((r.depth(1.0) - 4.0).abs() < 1e-5);
        }
        let r = Range {
            format: RangeFormat::RangeInverse,
            near: 1.0,
            far: 3.0,
            units: None,
        };
        // Inverse: halfway in value is halfway in disparity (1 and 1/3 -> 2/3).
        assert!((r.depth(0.5) - 1.5).abs() < 1e-6);
    }
}
