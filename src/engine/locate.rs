//! Where the files that ship beside the binary (models, helper scripts) are found at run
//! time. Nothing about the source tree is baked in at build time: a binary finds them from
//! the working directory, an environment variable, or where the binary itself lies, so
//! that a copied or installed binary works as well as the one in `target/`.

use std::path::{Path, PathBuf};

/// A folder holding the `models/` tree (`$RESHADER_MODELS/reshade`, `…/depth`), searched
/// before anything else.
pub const MODELS_ENV: &str = "RESHADER_MODELS";

/// How many folders above the binary's own are searched: `target/debug/reshader` finds
/// the checkout's files two levels up, an install's `bin/reshader` one level up.
const LEVELS_ABOVE_BINARY: usize = 3;

/// The places `rel` (a path such as `models/reshade`) is looked for, in order: the working
/// directory, then the binary's folder and the folders above it, each as `rel` and as
/// `share/reshader/rel` (the layout of an installation prefix).
pub fn candidates(rel: &str) -> Vec<PathBuf> {
    let mut out = vec![PathBuf::from(rel)];
    if let Some(exe_dir) = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(Path::to_path_buf))
    {
        for dir in exe_dir.ancestors().take(LEVELS_ABOVE_BINARY + 1) {
            out.push(dir.join(rel));
            out.push(dir.join("share/reshader").join(rel));
        }
    }
    out
}

/// The first of [`candidates`] that exists.
pub fn find(rel: &str) -> Option<PathBuf> {
    candidates(rel).into_iter().find(|p| p.exists())
}

/// The folders a kind of shipped model (`reshade`, `depth`, `fixtures`) is looked for in:
/// `$RESHADER_MODELS/<kind>` when that variable is set, then `models/<kind>` as
/// [`candidates`] finds it.
pub fn model_dirs(kind: &str) -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(root) = std::env::var_os(MODELS_ENV) {
        dirs.push(PathBuf::from(root).join(kind));
    }
    dirs.extend(candidates(&format!("models/{kind}")));
    dirs
}

/// The first of [`model_dirs`] that is a folder.
pub fn model_dir(kind: &str) -> Option<PathBuf> {
    model_dirs(kind).into_iter().find(|d| d.is_dir())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_working_directory_comes_first_then_the_binary() {
        let c = candidates("models/x");
        assert_eq!(c[0], PathBuf::from("models/x"));
        let exe_dir = std::env::current_exe()
            .unwrap()
            .parent()
            .unwrap()
            .to_path_buf();
        assert_eq!(c[1], exe_dir.join("models/x"));
        assert_eq!(c[2], exe_dir.join("share/reshader/models/x"));
        assert!(c.len() <= 2 + 2 * (LEVELS_ABOVE_BINARY + 1));
    }

    #[test]
    fn shipped_models_are_found_from_the_checkout() {
        // `cargo test` runs in the package root, where models/ ships.
        let dir = model_dir("fixtures").expect("models/fixtures is found");
        assert!(dir.join("reshade-fixture-fp32.json").is_file());
        assert!(model_dir("no-such-kind").is_none());
    }
}
