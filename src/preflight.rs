//! Checks made before any work, so that a run that cannot succeed says so at once
//! instead of after the depth network, the reshading and the relocation have run:
//! model paths that name the wrong kind of file, and (see [`estimate`]) memory the
//! sizes of a render would need.

use std::path::{Path, PathBuf};

/// A path given where a model manifest belongs.
#[derive(Debug, thiserror::Error)]
pub enum ModelPathError {
    #[error(
        "{flag} {path} is an ONNX graph; {flag} takes the model's manifest, the .json file \
         beside the .onnx: {manifest}{exists}"
    )]
    Onnx {
        flag: &'static str,
        path: PathBuf,
        manifest: PathBuf,
        exists: &'static str,
    },
    #[error(
        "{flag} {path} is not a model manifest (a .json file; it is not text): give the \
         manifest, or the directory that holds the models"
    )]
    NotText { flag: &'static str, path: PathBuf },
}

/// Refuses a reshading `--model` (or `$RESHADER_MODEL`) that names an ONNX file or
/// another binary file instead of a manifest, naming the manifest to give instead.
/// Directories and "none" pass; the loader checks manifests themselves.
pub fn check_model_path(flag: &'static str, path: &Path) -> Result<(), ModelPathError> {
    if path.as_os_str() == "none" || !path.is_file() {
        return Ok(());
    }
    let onnx = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("onnx"));
    if onnx {
        let manifest = path.with_extension("json");
        let exists = if manifest.is_file() {
            ""
        } else {
            " (which does not exist: every model ships with its manifest)"
        };
        return Err(ModelPathError::Onnx {
            flag,
            path: path.into(),
            manifest,
            exists,
        });
    }
    if !starts_as_text(path) {
        return Err(ModelPathError::NotText {
            flag,
            path: path.into(),
        });
    }
    Ok(())
}

/// The reshading model a command will load: `--model`, else `$RESHADER_MODEL`.
pub fn chosen_reshade_model(model: Option<&Path>) -> Option<PathBuf> {
    model
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
}

/// Whether the file's first 4 KiB are UTF-8 (a character cut at the end allowed).
fn starts_as_text(path: &Path) -> bool {
    use std::io::Read;
    let Ok(file) = std::fs::File::open(path) else {
        return true;
    };
    let mut head = Vec::with_capacity(4096);
    if file.take(4096).read_to_end(&mut head).is_err() {
        return true;
    }
    match std::str::from_utf8(&head) {
        Ok(_) => true,
        Err(e) => e.error_len().is_none(),
    }
}
