//! Measurements, built on the stages and the pipeline: the benchmark of every stage
//! ([`bench`](mod@bench)), the reshading benchmark and its fidelity ([`reshade`]), and the relocation
//! evaluation against rendered ground truth ([`relocation`]), with the statistics they
//! share ([`stats`]).

pub mod bench;
pub mod relocation;
pub mod reshade;
pub mod stats;
