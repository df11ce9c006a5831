//! The interleave crate's integration tests, in one test binary (`autotests = false` in
//! Cargo.toml). Run one group with its module path as the filter, e.g.
//! `cargo test -p interleave --test main mapping::`.

mod boards;
mod cells;
mod mapping;
mod weave;
