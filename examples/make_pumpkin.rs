//! Rebuilds `examples/pumpkin/` from the Tiefenrausch test photo and its reference
//! output (MIT licence, see examples/pumpkin/LICENSE):
//!
//! ```text
//! cargo run --example make_pumpkin -- ../shared/third_party/tiefenrausch examples/pumpkin
//! ```
//!
//! The photo is shrunk to the reference map's 288×384 (keeping its EXIF, which carries
//! the 35 mm-equivalent focal length), and the network's log-disparity is turned into
//! disparity (exp) and stored as a 16-bit PNG spanning the full 0..65535 range: relative
//! disparity is affine-ambiguous, so only its shape matters.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use image::codecs::jpeg::JpegEncoder;
use image::imageops::FilterType;
use image::{DynamicImage, ImageBuffer, ImageDecoder, ImageEncoder, ImageReader, Luma};

fn main() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [source, out] = args.as_slice() else {
        bail!("usage: make_pumpkin TIEFENRAUSCH_DIR OUT_DIR");
    };
    std::fs::create_dir_all(out)?;
    let disparity = read_disparity(&source.join("output/pumpkin.npy"))?;
    let (w, h) = (disparity.width(), disparity.height());
    write_photo(
        &source.join("input/pumpkin.jpg"),
        &out.join("pumpkin.jpg"),
        w,
        h,
    )?;
    disparity.save(out.join("pumpkin_disparity.png"))?;
    std::fs::copy(source.join("LICENSE"), out.join("LICENSE"))?;
    println!("wrote {w}x{h} photo and disparity to {}", out.display());
    Ok(())
}

fn read_disparity(path: &std::path::Path) -> Result<ImageBuffer<Luma<u16>, Vec<u16>>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let log_disp = reshader::io::npy::parse(&bytes).with_context(|| path.display().to_string())?;
    let disp: Vec<f32> = log_disp.data.iter().map(|v| v.exp()).collect();
    let lo = disp.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = disp.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let values = disp
        .iter()
        .map(|d| ((d - lo) / (hi - lo) * 65535.0).round() as u16)
        .collect();
    ImageBuffer::from_raw(log_disp.cols as u32, log_disp.rows as u32, values)
        .context("disparity size")
}

fn write_photo(input: &std::path::Path, output: &std::path::Path, w: u32, h: u32) -> Result<()> {
    let mut decoder = ImageReader::open(input)?
        .with_guessed_format()?
        .into_decoder()?;
    let exif = decoder.exif_metadata()?;
    let photo = DynamicImage::from_decoder(decoder)?
        .resize_exact(w, h, FilterType::Triangle)
        .to_rgb8();
    let mut encoder = JpegEncoder::new_with_quality(BufWriter::new(File::create(output)?), 90);
    if let Some(exif) = exif {
        encoder.set_exif_metadata(exif)?;
    }
    encoder.write_image(photo.as_raw(), w, h, image::ExtendedColorType::Rgb8)?;
    Ok(())
}
