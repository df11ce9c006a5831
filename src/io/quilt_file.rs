//! Quilt files: written with their layout in PNG text metadata as well as in their name,
//! and read back into views, so that a quilt from reshader or from other software can be
//! woven for a board.

use std::io::BufReader;
use std::path::{Path, PathBuf};

use image::RgbImage;
use interleave::{split_quilt, Board, QuiltLayout, QuiltLayoutError, WeaveError, Weaver};

use crate::io::output::{self, OutputError};
use crate::io::photo::PhotoError;

/// What goes wrong reading a quilt back and weaving it.
#[derive(Debug, thiserror::Error)]
pub enum QuiltFileError {
    #[error(transparent)]
    Image(#[from] PhotoError),
    #[error("{path}: cannot read its PNG metadata: {message}")]
    Metadata { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Layout {
        path: PathBuf,
        source: QuiltLayoutError,
    },
    #[error(
        "{path}: the quilt holds {views} views but board `{board}` shows {expected}; weave it \
         for a board with {views} views"
    )]
    ViewCount {
        path: PathBuf,
        views: usize,
        board: String,
        expected: usize,
    },
    #[error("{path}: {source}")]
    Weave { path: PathBuf, source: WeaveError },
}

/// A quilt as PNG bytes whose text chunks carry its layout (and what made it).
pub fn encode(path: &Path, quilt: &RgbImage, layout: &QuiltLayout) -> Result<Vec<u8>, OutputError> {
    let mut text = layout.text();
    text.push((
        "Software",
        format!("reshader {}", env!("CARGO_PKG_VERSION")),
    ));
    text.push((
        "Description",
        "Looking Glass quilt: view 0 bottom-left, then left to right, then upward".into(),
    ));
    output::encode_png_with_text(path, quilt, &text)
}

/// The views of a quilt file and its layout: from its PNG metadata, else its name.
pub fn read(path: &Path) -> Result<(Vec<RgbImage>, QuiltLayout), QuiltFileError> {
    let image = crate::io::photo::load_rgb8(path)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let layout =
        QuiltLayout::resolve(&name, &png_text(path)?, image.dimensions()).map_err(|source| {
            QuiltFileError::Layout {
                path: path.into(),
                source,
            }
        })?;
    let views = split_quilt(&image, layout.cols, layout.rows, layout.views).map_err(|source| {
        QuiltFileError::Weave {
            path: path.into(),
            source,
        }
    })?;
    Ok((views, layout))
}

/// Weaves a quilt file for `board`, whose view count it must hold.
pub fn weave(path: &Path, board: &Board) -> Result<RgbImage, QuiltFileError> {
    let (views, layout) = read(path)?;
    if layout.views != board.views() {
        return Err(QuiltFileError::ViewCount {
            path: path.into(),
            views: layout.views,
            board: board.name().into(),
            expected: board.views(),
        });
    }
    let (w, h) = views[0].dimensions();
    Weaver::new(board, w, h)
        .weave(&views)
        .map_err(|source| QuiltFileError::Weave {
            path: path.into(),
            source,
        })
}

/// The text chunks (tEXt, iTXt) ahead of a PNG's image data; none for other formats.
fn png_text(path: &Path) -> Result<Vec<(String, String)>, QuiltFileError> {
    let err = |message: String| QuiltFileError::Metadata {
        path: path.into(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut reader = BufReader::new(file);
    let mut signature = [0u8; 8];
    if std::io::Read::read_exact(&mut reader, &mut signature).is_err()
        || signature != [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n']
    {
        return Ok(Vec::new());
    }
    std::io::Seek::rewind(&mut reader).map_err(|e| err(e.to_string()))?;
    let png = png::Decoder::new(reader)
        .read_info()
        .map_err(|e| err(e.to_string()))?;
    let info = png.info();
    let mut text: Vec<(String, String)> = info
        .uncompressed_latin1_text
        .iter()
        .map(|t| (t.keyword.clone(), t.text.clone()))
        .collect();
    for chunk in &info.utf8_text {
        let value = chunk.get_text().map_err(|e| err(e.to_string()))?;
        text.push((chunk.keyword.clone(), value));
    }
    Ok(text)
}
