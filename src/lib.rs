//! reshader: turns one photo and its depth into the views, quilt and woven frame a
//! lenticular light-field panel shows.
//!
//! The modules follow the data flow (docs/architecture.md has the diagram):
//!
//! ```text
//! io (photo, depth files) ─▶ depth ─▶ views ─▶ reshade ─▶ relocate ─▶ interleave
//!                                   └────────── pipeline runs them in order ──────────┘
//!                                        device (camera, panel, gallery), eval (bench)
//! ```
//!
//! [`io`] holds the file formats every stage reads and writes; [`engine`] runs the
//! networks; [`depth`] turns the photo into a depth map; [`views`] places the view
//! cameras; [`reshade`] changes the shading per view; [`relocate`] moves the pixels to
//! the view; the `interleave` crate weaves the views for the panel; [`pipeline`] runs the
//! stages in order and writes the outputs and run.json; [`device`] and [`eval`] are built
//! on the pipeline. Imports go one way: io → engine → stages → pipeline → device and eval.

// Formats, engines and threads, below every stage.
pub mod io;
pub mod engine;
pub mod parallel;

// The stages, in data-flow order.
pub mod depth;
pub mod views;
pub mod reshade;
pub mod relocate;
pub use interleave;

// The stages in order, and what is built on them.
pub mod pipeline;
pub mod device;
pub mod eval;

/// What a program that renders photos for a panel needs, in one import:
///
/// ```no_run
/// use reshader::prelude::*;
///
/// let board = load_board("looking-glass-portrait", None)?;
/// let opts = RenderOptions {
///     photo: "photo.jpg".into(),
///     depth: SceneDepth::Estimate(DepthConfig::default().estimator(DepthSource::Auto)?.into()),
///     fov: None,
///     board,
///     board_file: None,
///     calibration: None,
///     focus: None,
///     depthiness: None,
///     shading_depthiness: None,
///     only: vec![Product::Panel],
///     sbs_pair: None,
///     out_dir: "out".into(),
///     progress: Progress::hidden(),
/// };
/// let reshader = ReshadeConfig::default().build()?;
/// let record = render(&opts, &*reshader, &*RelocateConfig::default().build())?;
/// println!("wrote {} files", record.outputs.len());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub mod prelude {
    pub use crate::depth::net::{DepthConfig, DepthSource};
    pub use crate::depth::{DepthKind, DepthMap};
    pub use crate::interleave::Board;
    pub use crate::pipeline::progress::Progress;
    pub use crate::pipeline::{load_board, render, Product, RenderOptions, Scene, SceneDepth};
    pub use crate::relocate::{RelocateConfig, Relocator};
    pub use crate::reshade::net::choice::ReshadeConfig;
    pub use crate::reshade::Reshader;
}
