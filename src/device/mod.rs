//! The device side, built on the pipeline: frames in from a camera or files
//! ([`capture`], with the live loop), frames out to a panel ([`display`]), and the
//! watched folder of photos a kiosk shows ([`gallery`]).

pub mod capture;
pub mod display;
pub mod gallery;
