//! Inference engines behind one interface: tract (pure Rust, the default) and, with the
//! `ort` cargo feature, onnxruntime loaded at run time from a `libonnxruntime.so`.
//!
//! A [`Plan`] is a model specialised to concrete input shapes: tract cannot analyse our
//! graphs with symbolic H/W, and both engines optimise better with every shape known, so
//! callers build one plan per working resolution and keep it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::engine::manifest::Precision;

mod fp16;
mod int8;
mod octaves;
mod pool;
mod proto;
mod sine;
mod transpose;
#[cfg(test)]
mod test_graphs;
pub mod locate;
pub mod manifest;
pub mod resample;
pub mod tract;

#[cfg(feature = "ort")]
pub mod ort;

/// A dense f32 tensor in row-major order.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Tensor {
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            data.len(),
            "tensor data does not fill its shape {shape:?}"
        );
        Self { shape, data }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    #[error("{engine} cannot load {path}: {message}")]
    Load {
        engine: &'static str,
        path: PathBuf,
        message: String,
    },
    #[error("{path}: the graph's {what} are {graph:?} but its manifest lists {manifest:?}")]
    Names {
        path: PathBuf,
        what: &'static str,
        graph: Vec<String>,
        manifest: Vec<String>,
    },
    #[error("{engine} failed running {path}: {message}")]
    Run {
        engine: &'static str,
        path: PathBuf,
        message: String,
    },
    #[error("unknown engine {0:?}: use tract{1}")]
    Unknown(String, &'static str),
}

/// Model bytes (already checked against their manifest) and what they hold.
#[derive(Clone, Copy, Debug)]
pub struct ModelSource<'a> {
    pub path: &'a Path,
    pub bytes: &'a [u8],
    pub precision: Precision,
}

pub trait Engine: Send + Sync {
    fn name(&self) -> &'static str;

    /// Threads one plan run uses.
    fn threads(&self) -> usize;

    /// Builds a plan for the given input shapes (by input name); the graph's input and
    /// output names must be exactly `inputs` and `outputs`.
    fn plan(
        &self,
        model: ModelSource<'_>,
        shapes: &[(&str, Vec<usize>)],
        outputs: &[&str],
    ) -> Result<Arc<dyn Plan>, EngineError>;
}

pub trait Plan: Send + Sync {
    /// Runs the graph; returns the outputs in the order `plan` was asked for.
    fn run(&self, inputs: &[(&str, &Tensor)]) -> Result<Vec<Tensor>, EngineError>;
}

/// Engine names `--engine` accepts in this build.
pub const ENGINES: &[&str] = if cfg!(feature = "ort") {
    &["tract", "ort"]
} else {
    &["tract"]
};

/// The engine called `name`, using `threads` threads per run.
pub fn by_name(name: &str, threads: usize) -> Result<Arc<dyn Engine>, EngineError> {
    match name {
        "tract" => Ok(Arc::new(tract::TractEngine::new(threads))),
        #[cfg(feature = "ort")]
        "ort" => Ok(Arc::new(ort::OrtEngine::new(threads)?)),
        _ => Err(EngineError::Unknown(
            name.to_owned(),
            if cfg!(feature = "ort") {
                " or ort"
            } else {
                " (this build has no onnxruntime engine: rebuild with --features ort)"
            },
        )),
    }
}

/// Checks that a graph's names are exactly the expected ones (in any order).
fn check_names(
    path: &Path,
    what: &'static str,
    graph: &[String],
    expected: &[&str],
) -> Result<(), EngineError> {
    let mut a: Vec<&str> = graph.iter().map(String::as_str).collect();
    let mut b = expected.to_vec();
    a.sort_unstable();
    b.sort_unstable();
    if a != b {
        return Err(EngineError::Names {
            path: path.to_owned(),
            what,
            graph: graph.to_vec(),
            manifest: expected.iter().map(|s| s.to_string()).collect(),
        });
    }
    Ok(())
}
