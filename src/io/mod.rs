//! File formats and files, below every stage: the run's memory ceiling every parser checks
//! ([`limits`]), the photo ([`photo`]), arrays and depth files ([`npy`], [`pfm`]), staged
//! atomic output ([`output`]), run.json ([`record`]), the quilt file ([`quilt_file`]), the
//! RGB-D image ([`rgbd`]) and the HTML and animated previews ([`preview`]).

pub mod keyword;
pub mod limits;
pub mod npy;
pub mod output;
pub mod pfm;
pub mod photo;
pub mod preview;
pub mod quilt_file;
pub mod record;
pub mod rgbd;
