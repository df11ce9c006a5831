//! reshader's integration tests, in one test binary (`autotests = false` in Cargo.toml):
//! linking tract into one binary instead of one per file saves most of the test build.
//! Each file below is one group; run one group with its module path as the filter, e.g.
//! `cargo test --test main spine_render::`.

// Helpers shared by several groups.
mod depth_support;
mod ldi_support;
mod reshade_support;
mod spine_support;

mod bench_report;
mod depth_cli;
mod depth_embedded;
mod depth_holes;
mod depth_models;
mod depth_reference;
mod depth_refine;
mod depth_render;
mod device_capture;
mod device_display;
mod device_gallery;
mod device_live;
mod fuzz_regressions;
mod hardening_corpus;
mod hardening_kill;
mod hardening_memory;
mod hardening_messages;
mod ldi_edges;
mod ldi_eval;
mod ldi_eval_cli;
mod ldi_properties;
mod progress_cli;
mod render_preview;
mod render_rgbd;
mod reshade_manifest;
mod reshade_net;
mod reshade_parity;
mod reshade_shipped;
mod spine_cli_errors;
mod spine_render;
mod weave_cli;
