//! Which files of a gallery are photos to convert, and the depth files beside them.

use std::path::{Path, PathBuf};

use crate::depth::DepthKind;

/// Depth files looked for beside a photo, in order: `NAME_depth.EXT` holds depth in
/// scene units, `NAME_disparity.EXT` relative disparity. Without one, the photo's
/// embedded depth or the depth network is used.
pub(crate) const DEPTH_SIDECARS: &[(&str, DepthKind)] = &[
    ("_depth", DepthKind::Depth),
    ("_disparity", DepthKind::Disparity),
];
pub(crate) const DEPTH_EXTENSIONS: &[&str] = &["npy", "png", "pfm", "exr"];

/// The photos among `convert`'s inputs, in order, and the inputs passed over with the
/// reason. A folder stands for the photos directly in it (sorted by name); what a
/// batch over `DIR/*` also catches is passed over: depth sidecars of photos beside
/// them, the batch's own `NAME.reshader/` output folders, files that are not JPEG or
/// PNG by name, and special files (FIFOs, sockets, devices), which are never opened.
/// A path that does not exist stays in, to fail with its own message.
pub fn collect_photos(inputs: &[PathBuf]) -> (Vec<PathBuf>, Vec<(PathBuf, String)>) {
    let (mut photos, mut passed) = (Vec::new(), Vec::new());
    for input in inputs {
        let Ok(meta) = std::fs::metadata(input) else {
            photos.push(input.clone());
            continue;
        };
        if meta.is_dir() {
            if is_output_dir(input) {
                passed.push((input.clone(), "a reshader output folder".into()));
                continue;
            }
            let Ok(entries) = std::fs::read_dir(input) else {
                photos.push(input.clone());
                continue;
            };
            let mut inside: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
            inside.sort();
            for path in inside {
                match std::fs::metadata(&path) {
                    Ok(m) if m.is_dir() => {}
                    Ok(m) => match pass_over(&path, &m) {
                        Some(why) => passed.push((path, why)),
                        None => photos.push(path),
                    },
                    Err(_) => {}
                }
            }
            continue;
        }
        match pass_over(input, &meta) {
            Some(why) => passed.push((input.clone(), why)),
            None => photos.push(input.clone()),
        }
    }
    (photos, passed)
}

/// Why a file among the inputs is not a photo to convert, if it is not.
fn pass_over(path: &Path, meta: &std::fs::Metadata) -> Option<String> {
    if !meta.is_file() {
        return Some(crate::io::limits::not_a_regular_file(meta).to_string());
    }
    if let Some(photo) = photo_of_sidecar(path) {
        return Some(format!("the depth sidecar of {}", photo.display()));
    }
    let name = path.file_name()?.to_string_lossy();
    if name.starts_with('.') {
        return Some("a hidden file".into());
    }
    let is_photo = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| PHOTO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
    (!is_photo).then(|| "not a JPEG or PNG (by its name)".into())
}

/// Photo file extensions `convert` takes from folders and globs.
const PHOTO_EXTENSIONS: &[&str] = &["jpg", "jpeg", "png"];

/// The photo beside `path` whose depth sidecar it is (`a_depth.png` beside `a.jpg`).
fn photo_of_sidecar(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?.to_str()?;
    let (stem, ext) = name.rsplit_once('.')?;
    if !DEPTH_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()) {
        return None;
    }
    let photo_stem = DEPTH_SIDECARS
        .iter()
        .find_map(|(suffix, _)| stem.strip_suffix(suffix))?;
    PHOTO_EXTENSIONS
        .iter()
        .flat_map(|e| [e.to_string(), e.to_ascii_uppercase()])
        .map(|e| path.with_file_name(format!("{photo_stem}.{e}")))
        .find(|p| p.is_file())
}

/// Whether `dir` is an output folder of `convert`/`render`: named `NAME.reshader` or
/// holding a done-marker or a run.json.
fn is_output_dir(dir: &Path) -> bool {
    dir.file_name()
        .is_some_and(|n| n.to_string_lossy().ends_with(super::BESIDE_SUFFIX))
        || dir.join(super::DONE_MARKER).is_file()
        || dir.join("run.json").is_file()
}

/// The depth map beside `photo`, and how to read it.
pub fn find_depth(photo: &Path) -> Option<(PathBuf, DepthKind)> {
    let stem = photo
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    for (suffix, kind) in DEPTH_SIDECARS {
        for ext in DEPTH_EXTENSIONS {
            let candidate = photo.with_file_name(format!("{stem}{suffix}.{ext}"));
            if candidate.is_file() {
                return Some((candidate, *kind));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_sidecars_are_found_by_name_and_kind() {
        let dir = tempfile::tempdir().unwrap();
        let photo = dir.path().join("img.jpg");
        assert_eq!(find_depth(&photo), None);
        std::fs::write(dir.path().join("img_disparity.png"), b"").unwrap();
        assert_eq!(
            find_depth(&photo).unwrap(),
            (dir.path().join("img_disparity.png"), DepthKind::Disparity)
        );
        std::fs::write(dir.path().join("img_depth.exr"), b"").unwrap();
        assert_eq!(find_depth(&photo).unwrap().1, DepthKind::Depth);
    }
}
