//! reshader: turns one photo and its depth into the views, quilt and woven frame a
//! lenticular light-field panel shows.
//!
//! Stages, each behind its own module: [`photo`] and [`depth`] load the inputs, [`views`]
//! places the view cameras, [`reshade`] changes the shading per view, [`relocate`] moves
//! the pixels to the view, and [`pipeline`] runs them in order and hands the views to the
//! `interleave` crate; [`output`] and [`record`] write the results and run.json.

pub mod bench;
pub mod bench_reshade;
pub mod capture;
pub mod depth;
pub mod depth_holes;
pub mod depth_net;
pub mod depth_refine;
pub mod display;
pub mod embedded_depth;
pub mod engine;
pub mod eval_relocation;
pub mod gallery;
pub mod ldi;
pub mod limits;
pub mod manifest;
pub mod npy;
pub mod output;
pub mod pfm;
pub mod photo;
pub mod pipeline;
pub mod preflight;
pub mod preview;
pub mod progress;
pub mod quilt_file;
pub mod record;
pub mod relocate;
pub mod reshade;
pub mod reshade_net;
pub mod rgbd;
pub mod views;

pub use interleave;
