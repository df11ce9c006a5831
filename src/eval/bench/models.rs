//! Which reshading model the benchmark times, and the untrained networks and Python it
//! needs for the comparisons, found at run time (see [`crate::engine::locate`]).

use std::path::{Path, PathBuf};

use crate::engine::manifest::{self, Precision, Task};
use crate::reshade::net::choice::{Head, DEFAULT_HEAD};

use super::{io_err, BenchConfig, BenchError, ModelChoice};

/// --model, else $RESHADER_MODEL, else models/reshade when it has the precision asked
/// for, else the untrained stand-in (exported once), else the fixture.
pub fn choose_model(args: &BenchConfig) -> Result<ModelChoice, BenchError> {
    let precision = args.reshade.precision_for(args.reshade.model.as_deref());
    if let Some(p) = args
        .reshade
        .model
        .clone()
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
    {
        return Ok(ModelChoice::Given(p));
    }
    let shipped = crate::reshade::net::choice::default_model_dir()
        .unwrap_or_else(|| PathBuf::from("models/reshade"));
    let head = args.reshade.head.unwrap_or(DEFAULT_HEAD);
    if shipped.is_dir() && !reshade_manifests(&shipped, Some(precision), head)?.is_empty() {
        return Ok(ModelChoice::Shipped(shipped));
    }
    log::warn!(
        "no {precision} {head}-head reshading model in {}: timing a stand-in",
        shipped.display()
    );
    // The untrained stand-in is the residual head's architecture.
    if precision != Precision::Int8 && head == Head::Residual {
        match untrained_model(args, precision) {
            Ok(path) => return Ok(ModelChoice::Untrained(path)),
            Err(e) => log::warn!("untrained stand-in not available ({e}); using the fixture"),
        }
    }
    Ok(ModelChoice::Fixture(
        crate::engine::locate::model_dir("fixtures")
            .unwrap_or_else(|| PathBuf::from("models/fixtures")),
    ))
}

/// A benchmark script, from the checkout the binary runs in or beside (`bench/NAME`).
pub(super) fn script(name: &str) -> PathBuf {
    let rel = format!("bench/{name}");
    crate::engine::locate::find(&rel).unwrap_or_else(|| PathBuf::from(rel))
}

fn cache_home() -> PathBuf {
    std::env::var_os("HOME")
        .map_or_else(std::env::temp_dir, PathBuf::from)
        .join(".cache/reshader")
}

pub(super) fn python(args: &BenchConfig) -> Result<PathBuf, BenchError> {
    if let Some(p) = args
        .python
        .clone()
        .or_else(|| std::env::var_os("RESHADER_PYTHON").map(PathBuf::from))
    {
        return Ok(p);
    }
    let venv = cache_home().join("venv/bin/python");
    if venv.is_file() {
        return Ok(venv);
    }
    let env_script = crate::engine::locate::find("scripts/python-env")
        .unwrap_or_else(|| PathBuf::from("scripts/python-env"));
    let out = std::process::Command::new(&env_script)
        .output()
        .map_err(io_err(&env_script))?;
    let venv = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    if !out.status.success() || venv.is_empty() {
        return Err(BenchError::Usage(format!(
            "no Python with onnxruntime: {} failed; pass --python or --no-peer --no-naive",
            env_script.display()
        )));
    }
    Ok(PathBuf::from(venv).join("bin/python"))
}

/// The reshading manifests of `model` at `precision` (None: every precision) for `head`.
/// For a directory: its manifests of that head, leaving out a precision's single graph
/// when the pair of that precision is there (the runtime runs the pair). For a manifest:
/// it and, for one half of a pair, the other half beside it.
pub(super) fn reshade_manifests(
    model: &Path,
    precision: Option<Precision>,
    head: Head,
) -> Result<Vec<PathBuf>, BenchError> {
    if model.is_file() {
        let mut files = vec![model.to_owned()];
        let name = model
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let partner = if name.contains("decoder") {
            name.replace("decoder", "encoder")
        } else {
            name.replace("encoder", "decoder")
        };
        let partner = model.with_file_name(&partner);
        if partner != model && partner.is_file() {
            files.insert(0, partner);
        }
        return Ok(files);
    }
    let mut found: Vec<(PathBuf, manifest::Manifest)> = std::fs::read_dir(model)
        .map_err(io_err(model))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .filter_map(|p| manifest::Manifest::load(&p).ok().map(|m| (p, m)))
        .filter(|(_, m)| {
            precision.is_none_or(|p| m.precision == p)
                && match head {
                    Head::Residual => crate::reshade::net::is_residual(m.task),
                    Head::Lobes => m.task == Task::ReshadeLobes,
                }
        })
        .collect();
    let split: Vec<Precision> = found
        .iter()
        .filter(|(_, m)| m.task == Task::ReshadeDecoder)
        .map(|(_, m)| m.precision)
        .collect();
    found.retain(|(_, m)| m.task != Task::Reshade || !split.contains(&m.precision));
    let mut paths: Vec<PathBuf> = found.into_iter().map(|(p, _)| p).collect();
    paths.sort();
    Ok(paths)
}

/// The shipped architecture's size, for the untrained stand-in.
const STAND_IN_SIZE: &str = "lite";

/// The untrained stand-in's decoder manifest (its encoder is found beside it).
pub(super) fn untrained_model(
    args: &BenchConfig,
    precision: Precision,
) -> Result<PathBuf, BenchError> {
    let stem = cached_export(args, STAND_IN_SIZE, true, precision)?;
    Ok(stem.with_file_name(format!(
        "{}-decoder.json",
        stem.file_stem().unwrap_or_default().to_string_lossy()
    )))
}

/// A randomly initialised network of `size` exported once into the cache by
/// bench/export_untrained.py; the single graph's manifest.
pub(super) fn cached_export(
    args: &BenchConfig,
    size: &str,
    split: bool,
    precision: Precision,
) -> Result<PathBuf, BenchError> {
    let dir = args
        .cache
        .clone()
        .unwrap_or_else(|| cache_home().join("bench"));
    let stem = format!("reshade-{size}-untrained-{precision}");
    let manifest = dir.join(format!("{stem}.json"));
    let decoder = dir.join(format!("{stem}-decoder.json"));
    if manifest.is_file() && (!split || decoder.is_file()) {
        return Ok(manifest);
    }
    let py = python(args)?;
    let exporter = script("export_untrained.py");
    log::info!(
        "exporting an untrained {size} network to {} (once)",
        dir.display()
    );
    let mut command = std::process::Command::new(&py);
    command
        .arg(&exporter)
        .arg("--out")
        .arg(&dir)
        .arg("--size")
        .arg(size)
        .arg("--precision")
        .arg(precision.to_string());
    if split {
        command.arg("--split");
    }
    let status = command.status().map_err(io_err(&py))?;
    if !status.success() || !manifest.is_file() {
        return Err(BenchError::Peer {
            script: exporter,
            problem: format!(
                "exited with {status} without writing {}",
                manifest.display()
            ),
        });
    }
    Ok(manifest)
}
