//! Which model files make up a reshading network: an encoder and decoder pair, or one
//! graph, found from a manifest, a graph or a model directory for the asked precision,
//! each checked against its manifest.

use std::path::{Path, PathBuf};

use crate::engine::manifest::{self, ManifestError, Precision, Task, VerifiedModel};

use super::{Form, NetError};

/// Finds the reshading graphs at `path` for `precision` and checks their manifests.
pub(super) fn find_models(path: &Path, precision: Precision) -> Result<Form, NetError> {
    if path.is_dir() {
        return find_in_dir(path, precision);
    }
    let m = manifest::Manifest::load(path)?;
    let partner = match m.task {
        Task::Reshade => {
            return Ok(Form::Single(Box::new(verified(
                path,
                Task::Reshade,
                precision,
            )?)))
        }
        Task::ReshadeEncoder => Task::ReshadeDecoder,
        Task::ReshadeDecoder => Task::ReshadeEncoder,
        Task::ReshadeLobes => {
            return Err(NetError::Model {
                path: path.to_owned(),
                problem: "is a lobe-head model (task \"reshade-lobes\"): load it with --head lobes (or by its manifest alone, without --head residual)".into(),
            })
        }
        other => {
            return Err(manifest::field_error(
                path,
                "task",
                format!("is {:?}; a reshading model is needed", other.to_string()),
            )
            .into())
        }
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let candidates = reshade_manifests(dir, precision)?;
    let wanted = partner_name(&m.name, m.task);
    let other = candidates
        .iter()
        .find(|(_, c)| c.task == partner && c.name == wanted)
        .ok_or_else(|| NetError::Model {
            path: path.to_owned(),
            problem: format!("is one half of an encoder/decoder pair but {dir:?} has no {partner} manifest named {wanted:?}"),
        })?;
    pair(path, &other.0, m.task, precision)
}

pub(super) fn partner_name(name: &str, task: Task) -> String {
    match task {
        Task::ReshadeEncoder => name.replace("encoder", "decoder"),
        _ => name.replace("decoder", "encoder"),
    }
}

pub(super) fn pair(
    a: &Path,
    b: &Path,
    a_task: Task,
    precision: Precision,
) -> Result<Form, NetError> {
    let (enc, dec) = if a_task == Task::ReshadeEncoder {
        (a, b)
    } else {
        (b, a)
    };
    let encoder = verified(enc, Task::ReshadeEncoder, precision)?;
    let decoder = verified(dec, Task::ReshadeDecoder, precision)?;
    if encoder.manifest.version != decoder.manifest.version {
        return Err(manifest::field_error(
            dec,
            "version",
            format!(
                "is {:?} but the encoder's is {:?}: the halves come from different exports",
                decoder.manifest.version, encoder.manifest.version
            ),
        )
        .into());
    }
    Ok(Form::Split {
        encoder: Box::new(encoder),
        decoder: Box::new(decoder),
    })
}

pub(super) fn verified(
    path: &Path,
    task: Task,
    precision: Precision,
) -> Result<VerifiedModel, NetError> {
    let model = manifest::load_verified(path)?;
    manifest::check_reshade(path, &model.manifest, task, precision)?;
    Ok(model)
}

/// Whether a manifest's task is one of the residual head's graph forms (the paper's
/// network: single graph or encoder/decoder pair).
pub fn is_residual(task: Task) -> bool {
    matches!(
        task,
        Task::Reshade | Task::ReshadeEncoder | Task::ReshadeDecoder
    )
}

/// Manifests in `dir` at `precision` (None: any) whose task passes `wanted` (others, and
/// files that are not manifests, are skipped), sorted by path.
pub fn manifests_where(
    dir: &Path,
    precision: Option<Precision>,
    wanted: impl Fn(Task) -> bool,
) -> Result<Vec<(PathBuf, manifest::Manifest)>, NetError> {
    let entries = std::fs::read_dir(dir).map_err(|source| ManifestError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let mut found = Vec::new();
    for entry in entries.flatten() {
        let p = entry.path();
        if p.extension().is_none_or(|e| e != "json") {
            continue;
        }
        match manifest::Manifest::load(&p) {
            Ok(m) if wanted(m.task) && precision.is_none_or(|want| m.precision == want) => {
                found.push((p, m))
            }
            Ok(_) => {}
            Err(e) => log::debug!("skipping {}: {e}", p.display()),
        }
    }
    found.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(found)
}

/// Residual-head reshading manifests in `dir` at `precision`.
pub(super) fn reshade_manifests(
    dir: &Path,
    precision: Precision,
) -> Result<Vec<(PathBuf, manifest::Manifest)>, NetError> {
    manifests_where(dir, Some(precision), is_residual)
}

/// "; it has fp32 (--precision fp32)" when `dir` holds models of the head `wanted`
/// selects at other precisions than the one asked for, so that the error says what would
/// load.
pub(crate) fn other_precisions(dir: &Path, asked: Precision, wanted: fn(Task) -> bool) -> String {
    let found: Vec<String> = [Precision::Int8, Precision::Fp32, Precision::Fp16]
        .into_iter()
        .filter(|&p| p != asked)
        .filter(|&p| manifests_where(dir, Some(p), wanted).is_ok_and(|m| !m.is_empty()))
        .map(|p| format!("{p} (--precision {p})"))
        .collect();
    if found.is_empty() {
        String::new()
    } else {
        format!("; it has {}", found.join(", "))
    }
}

/// "; it also holds <head> models: [files] (--head <head>)" when `dir` has models of the
/// other head, so that an error about the asked head names what is there.
pub(crate) fn other_head(dir: &Path, wanted: fn(Task) -> bool, head: &str) -> String {
    let files: Vec<String> = manifests_where(dir, None, wanted)
        .unwrap_or_default()
        .into_iter()
        .filter_map(|(p, _)| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    if files.is_empty() {
        String::new()
    } else {
        format!("; it also holds {head}-head models {files:?} (--head {head})")
    }
}

pub(super) fn find_in_dir(dir: &Path, precision: Precision) -> Result<Form, NetError> {
    let found = reshade_manifests(dir, precision)?;
    let of = |task: Task| -> Vec<&PathBuf> {
        found
            .iter()
            .filter(|(_, m)| m.task == task)
            .map(|(p, _)| p)
            .collect()
    };
    let (encoders, decoders, singles) = (
        of(Task::ReshadeEncoder),
        of(Task::ReshadeDecoder),
        of(Task::Reshade),
    );
    let none = || NetError::Model {
        path: dir.to_owned(),
        problem: format!(
            "holds no residual-head reshading model manifest with precision {precision}{}{}",
            other_precisions(dir, precision, is_residual),
            other_head(dir, |t| t == Task::ReshadeLobes, "lobes"),
        ),
    };
    let ambiguous = |what: &str, list: &[&PathBuf]| NetError::Model {
        path: dir.to_owned(),
        problem: format!(
            "holds several {precision} {what}: {list:?}; pass one manifest with --model"
        ),
    };
    if !encoders.is_empty() || !decoders.is_empty() {
        if encoders.len() != 1 || decoders.len() != 1 {
            let all: Vec<&PathBuf> = encoders.iter().chain(&decoders).copied().collect();
            return Err(ambiguous(
                "encoder/decoder manifests (need exactly one of each)",
                &all,
            ));
        }
        return pair(encoders[0], decoders[0], Task::ReshadeEncoder, precision);
    }
    match singles.as_slice() {
        [one] => Ok(Form::Single(Box::new(verified(
            one,
            Task::Reshade,
            precision,
        )?))),
        [] => Err(none()),
        many => Err(ambiguous("single-graph manifests", many)),
    }
}
