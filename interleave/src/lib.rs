//! Subpixel-to-view mapping, weaving and quilts for slanted-lenticular light-field panels.
//!
//! * [`Board`]: a panel description loaded from TOML (built in, or a file), optionally
//!   overridden by a unit's Looking-Glass calibration ([`Calibration`]).
//! * [`Mapping`]: the per-subpixel view assignment every board reduces to.
//! * [`Weaver`]: the mapping baked into lookup tables for one view size; weaving a frame
//!   is a gather from the N view images.
//! * [`make_quilt`], [`split_quilt`], [`quilt_file_name`], [`side_by_side`]: the other
//!   output forms.
//!
//! See `README.md` beside this crate for the mapping's derivation and the board format.

pub mod board;
pub mod calibration;
pub mod cells;
pub mod filter;
pub mod lens;
pub mod mapping;
pub mod quilt;
pub mod validate;
pub mod weave;

pub use board::Board;
pub use calibration::Calibration;
pub use cells::{CellPattern, SubpixelCell};
pub use filter::{Blend, UnknownBlend, ViewFilter};
pub use lens::{Lens, LookingGlass, SideBySide, SubpixelLayout, VanBerkel};
pub use mapping::{LensPhase, Mapping};
pub use quilt::{
    make_quilt, quilt_file_name, side_by_side, split_quilt, QuiltLayout, QuiltLayoutError,
};
pub use validate::BoardError;
pub use weave::{WeaveError, Weaver};
