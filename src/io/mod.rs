//! File formats and files, below every stage: the run's memory ceiling every parser checks
//! ([`limits`]), the photo ([`photo`]), arrays and depth files ([`npy`], [`pfm`]), staged
//! atomic output ([`output`]), file records and stage timings ([`record`]), the quilt file
//! ([`quilt_file`]), the HTML and animated previews ([`preview`]), and the names options
//! are chosen by ([`keyword`]).

pub mod keyword;
pub mod limits;
pub mod npy;
pub mod output;
pub mod pfm;
pub mod photo;
pub mod preview;
pub mod quilt_file;
pub mod record;
