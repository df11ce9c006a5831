//! `reshader depth`'s work: a photo's estimated depth written to a depth file.

use std::path::Path;

use crate::depth::{DepthError, DepthMap};
use crate::io::output::{self, OutputError};
use crate::io::photo::PhotoError;

use super::{DepthEstimator, DepthNetError, StageReport};

#[derive(Debug, thiserror::Error)]
pub enum DepthFileError {
    #[error(transparent)]
    Photo(#[from] PhotoError),
    #[error(transparent)]
    Net(#[from] DepthNetError),
    #[error(transparent)]
    Depth(#[from] DepthError),
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// The depth formats a depth file can be written in.
pub const DEPTH_FILE_FORMATS: &[output::FileFormat] = &[
    output::FileFormat::Npy,
    output::FileFormat::Pfm,
    output::FileFormat::Exr,
    output::FileFormat::Png,
];

/// Refuses an output path `write_depth_file` could not write, before any work.
pub fn check_depth_file(out: &Path) -> Result<(), OutputError> {
    output::FileFormat::require(out, DEPTH_FILE_FORMATS)?;
    output::check_output_file(out)
}

/// Estimates the depth of the photo at `photo` and writes it to `out` (by its extension:
/// .npy float32, .pfm, .exr, or 16-bit .png in thousandths), atomically.
pub fn write_depth_file(
    estimator: &DepthEstimator,
    photo: &Path,
    out: &Path,
) -> Result<(DepthMap, StageReport), DepthFileError> {
    check_depth_file(out)?;
    let image = crate::io::photo::load_rgb8(photo)?;
    let mut timings = crate::io::record::Timings::default();
    let size = super::photo_size(&image);
    let (map, report) = estimator.depth(photo, &image, size, &mut timings)?;
    let bytes = map.encode(out)?;
    output::write_atomic(out, &bytes)?;
    Ok((map, report))
}
