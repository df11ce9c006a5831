//! Timing one ONNX file at fixed input shapes with tract, and the same file with
//! onnxruntime through `bench/peer_onnxruntime.py`, so the two engines see identical
//! graphs and shapes.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::engine::manifest::{self, Dim, VerifiedModel};
use crate::engine::{self, ModelSource, Tensor};

use super::report::Stat;
use super::BenchError;

/// One ONNX file and the concrete shape of each of its inputs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Job {
    pub label: String,
    pub path: PathBuf,
    pub inputs: Vec<(String, Vec<usize>)>,
    #[serde(skip)]
    pub outputs: Vec<String>,
    #[serde(skip)]
    pub manifest: PathBuf,
}

impl Job {
    /// The job for a manifest's model with its symbolic H and W set to `height`×`width`.
    pub fn for_manifest(
        label: &str,
        model: &VerifiedModel,
        height: usize,
        width: usize,
    ) -> Result<Job, BenchError> {
        let mut inputs = Vec::new();
        for spec in &model.manifest.inputs {
            let shape = spec
                .shape
                .iter()
                .map(|d| resolve_dim(d, height, width))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| BenchError::Model {
                    path: model.manifest_path.clone(),
                    problem: format!(
                        "input {} has a shape {:?} the benchmark cannot resolve",
                        spec.name, spec.shape
                    ),
                })?;
            inputs.push((spec.name.clone(), shape));
        }
        Ok(Job {
            label: label.into(),
            path: model.model_path.clone(),
            inputs,
            outputs: model
                .manifest
                .outputs
                .iter()
                .map(|o| o.name.clone())
                .collect(),
            manifest: model.manifest_path.clone(),
        })
    }

    pub fn shapes_text(&self) -> String {
        self.inputs
            .iter()
            .map(|(n, s)| {
                format!(
                    "{n} {}",
                    s.iter().map(usize::to_string).collect::<Vec<_>>().join("×")
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// A manifest dimension with `H` and `W` (optionally divided, `H/32`) made concrete.
pub fn resolve_dim(dim: &Dim, height: usize, width: usize) -> Option<usize> {
    match dim {
        Dim::Fixed(n) => usize::try_from(*n).ok(),
        Dim::Symbol(s) => {
            let (name, div) = match s.split_once('/') {
                Some((n, d)) => (n.trim(), d.trim().parse::<usize>().ok().filter(|&d| d > 0)?),
                None => (s.trim(), 1),
            };
            let base = match name {
                "H" => height,
                "W" => width,
                _ => return None,
            };
            Some(base / div)
        }
    }
}

/// Deterministic inputs in [0, 1): the engines' speed does not depend on the values, but
/// NaNs or denormals would.
fn inputs_for(job: &Job) -> Vec<(String, Tensor)> {
    job.inputs
        .iter()
        .map(|(name, shape)| {
            let n: usize = shape.iter().product();
            let data = (0..n)
                .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
                .collect();
            (name.clone(), Tensor::new(shape.clone(), data))
        })
        .collect()
}

/// Median/min/max of `runs` tract runs after one untimed warm-up run.
pub fn time_tract(job: &Job, threads: usize, runs: usize) -> Result<Stat, BenchError> {
    let model = manifest::load_verified(&job.manifest)?;
    let engine = engine::by_name("tract", threads)?;
    let shapes: Vec<(&str, Vec<usize>)> = job
        .inputs
        .iter()
        .map(|(n, s)| (n.as_str(), s.clone()))
        .collect();
    let outputs: Vec<&str> = job.outputs.iter().map(String::as_str).collect();
    let plan = engine.plan(
        ModelSource {
            path: &model.model_path,
            bytes: &model.bytes,
            precision: model.manifest.precision,
        },
        &shapes,
        &outputs,
    )?;
    let inputs = inputs_for(job);
    let refs: Vec<(&str, &Tensor)> = inputs.iter().map(|(n, t)| (n.as_str(), t)).collect();
    plan.run(&refs)?;
    let mut samples = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let started = Instant::now();
        plan.run(&refs)?;
        samples.push(started.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Stat::of(&samples).expect("at least one run"))
}

#[derive(Serialize)]
struct PeerRequest<'a> {
    threads: usize,
    runs: usize,
    models: &'a [Job],
}

#[derive(Deserialize)]
struct PeerAnswer {
    onnxruntime: String,
    results: Vec<PeerResult>,
}

#[derive(Deserialize)]
struct PeerResult {
    label: String,
    median_ms: Option<f64>,
    min_ms: Option<f64>,
    max_ms: Option<f64>,
    runs: Option<usize>,
    error: Option<String>,
}

/// onnxruntime's version and, per job label, its timing or the error it reported.
pub type PeerTimes = (String, Vec<(String, Result<Stat, String>)>);

/// Runs `script` with `python`, handing it the jobs as JSON on stdin.
pub fn time_onnxruntime(
    python: &Path,
    script: &Path,
    jobs: &[Job],
    threads: usize,
    runs: usize,
) -> Result<PeerTimes, BenchError> {
    let peer_err = |problem: String| BenchError::Peer {
        script: script.to_owned(),
        problem,
    };
    let request = serde_json::to_vec(&PeerRequest {
        threads,
        runs,
        models: jobs,
    })
    .expect("request serialises");
    let mut child = Command::new(python)
        .arg(script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| peer_err(format!("cannot start {}: {e}", python.display())))?;
    child
        .stdin
        .take()
        .expect("stdin is piped")
        .write_all(&request)
        .map_err(|e| peer_err(format!("cannot send the jobs: {e}")))?;
    let output = child
        .wait_with_output()
        .map_err(|e| peer_err(e.to_string()))?;
    if !output.status.success() {
        return Err(peer_err(format!(
            "exited with {}: {}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    parse_answer(&output.stdout).map_err(peer_err)
}

fn parse_answer(stdout: &[u8]) -> Result<PeerTimes, String> {
    let answer: PeerAnswer =
        serde_json::from_slice(stdout).map_err(|e| format!("printed no valid JSON: {e}"))?;
    let results = answer
        .results
        .into_iter()
        .map(|r| {
            let stat = match (r.median_ms, r.min_ms, r.max_ms, r.runs) {
                (Some(median_ms), Some(min_ms), Some(max_ms), Some(runs)) => Ok(Stat {
                    median_ms,
                    min_ms,
                    max_ms,
                    runs,
                }),
                _ => Err(r.error.unwrap_or_else(|| "no timing reported".into())),
            };
            (r.label, stat)
        })
        .collect();
    Ok((answer.onnxruntime, results))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dims_resolve_with_divisors_and_reject_unknown_symbols() {
        assert_eq!(resolve_dim(&Dim::Fixed(3), 64, 96), Some(3));
        assert_eq!(resolve_dim(&Dim::Symbol("H".into()), 64, 96), Some(64));
        assert_eq!(resolve_dim(&Dim::Symbol("W/32".into()), 64, 96), Some(3));
        assert_eq!(resolve_dim(&Dim::Symbol("N".into()), 64, 96), None);
        assert_eq!(resolve_dim(&Dim::Symbol("H/0".into()), 64, 96), None);
    }

    #[test]
    fn peer_answers_keep_errors_per_model() {
        let text = br#"{"onnxruntime": "1.2", "results": [
            {"label": "a", "median_ms": 2.0, "min_ms": 1.0, "max_ms": 3.0, "runs": 3},
            {"label": "b", "error": "cannot load"}]}"#;
        let (version, results) = parse_answer(text).unwrap();
        assert_eq!(version, "1.2");
        assert_eq!(results[0].1.as_ref().unwrap().median_ms, 2.0);
        assert_eq!(results[1].1.as_ref().unwrap_err(), "cannot load");
        assert!(parse_answer(b"not json").is_err());
    }
}
