//! Writing results: every file goes to a temporary name in its destination directory and
//! is renamed into place, and a multi-file run is staged whole before anything appears,
//! so a failure never leaves half-written or partial outputs behind.

use std::fs;
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use image::{ImageFormat, RgbImage};

use crate::npy;
use crate::photo::SrgbImage;

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot encode {path}: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: unknown output type; use one of {allowed}")]
    Extension { path: PathBuf, allowed: String },
}

/// File types chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileFormat {
    Png,
    Exr,
    Npy,
    Pfm,
}

impl FileFormat {
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(Self::Png),
            "exr" => Some(Self::Exr),
            "npy" => Some(Self::Npy),
            "pfm" => Some(Self::Pfm),
            _ => None,
        }
    }

    /// The format of `path` if it is one of `allowed`, else an error listing them.
    pub fn require(path: &Path, allowed: &[Self]) -> Result<Self, OutputError> {
        Self::from_path(path)
            .filter(|f| allowed.contains(f))
            .ok_or_else(|| OutputError::Extension {
                path: path.into(),
                allowed: allowed
                    .iter()
                    .map(|f| format!(".{}", f.extension()))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    pub fn extension(self) -> &'static str {
        match self {
            Self::Png => "png",
            Self::Exr => "exr",
            Self::Npy => "npy",
            Self::Pfm => "pfm",
        }
    }
}

/// Image outputs: PNG (8-bit sRGB), EXR (float, the same sRGB-encoded values) or npy
/// (float32, H×W×3).
pub const IMAGE_FORMATS: &[FileFormat] = &[FileFormat::Png, FileFormat::Exr, FileFormat::Npy];

pub fn encode_image(
    path: &Path,
    image: &SrgbImage,
    format: FileFormat,
) -> Result<Vec<u8>, OutputError> {
    match format {
        FileFormat::Png => encode_png(path, &image.to_rgb8()),
        FileFormat::Exr => {
            let mut buf = Cursor::new(Vec::new());
            image
                .to_rgb32f()
                .write_to(&mut buf, ImageFormat::OpenExr)
                .map_err(|source| OutputError::Encode {
                    path: path.into(),
                    source,
                })?;
            Ok(buf.into_inner())
        }
        FileFormat::Npy => Ok(npy::encode_f32(
            &[image.height() as usize, image.width() as usize, 3],
            image.data(),
        )),
        FileFormat::Pfm => Err(OutputError::Extension {
            path: path.into(),
            allowed: ".png, .exr, .npy".into(),
        }),
    }
}

pub fn encode_png(path: &Path, image: &RgbImage) -> Result<Vec<u8>, OutputError> {
    let mut buf = Cursor::new(Vec::new());
    image
        .write_to(&mut buf, ImageFormat::Png)
        .map_err(|source| OutputError::Encode {
            path: path.into(),
            source,
        })?;
    Ok(buf.into_inner())
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename,
/// so readers see either the old file or the complete new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let io_err = |source| OutputError::Io {
        path: path.into(),
        source,
    };
    let dir = parent_dir(path);
    let name = path.file_name().ok_or_else(|| {
        io_err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "path has no file name",
        ))
    })?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = write_and_sync(&tmp, bytes).and_then(|()| fs::rename(&tmp, path));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(io_err)
}

fn write_and_sync(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = fs::File::create(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The files of one run, written into a hidden directory beside the destination and
/// moved into the destination only by [`Staging::commit`]. Dropping an uncommitted
/// staging area deletes it.
pub struct Staging {
    out_dir: PathBuf,
    stage_dir: PathBuf,
    files: Vec<PathBuf>,
}

impl Staging {
    pub fn new(out_dir: &Path) -> Result<Self, OutputError> {
        let parent = parent_dir(out_dir);
        let name = out_dir
            .file_name()
            .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
        let stage_dir = parent.join(format!(".{name}.staging-{}", std::process::id()));
        let _ = fs::remove_dir_all(&stage_dir);
        fs::create_dir_all(&stage_dir).map_err(|source| OutputError::Io {
            path: stage_dir.clone(),
            source,
        })?;
        Ok(Self {
            out_dir: out_dir.into(),
            stage_dir,
            files: Vec::new(),
        })
    }

    /// Stages `bytes` under the relative path `rel` (e.g. `views/view_00.png`).
    pub fn write(&mut self, rel: &str, bytes: &[u8]) -> Result<(), OutputError> {
        let path = self.stage_dir.join(rel);
        let io_err = |source| OutputError::Io {
            path: self.out_dir.join(rel),
            source,
        };
        fs::create_dir_all(parent_dir(&path)).map_err(io_err)?;
        fs::write(&path, bytes).map_err(io_err)?;
        self.files.push(rel.into());
        Ok(())
    }

    /// Relative paths staged so far, in order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Where a staged file will end up.
    pub fn final_path(&self, rel: &str) -> PathBuf {
        self.out_dir.join(rel)
    }

    /// Moves every staged file into the destination; view files left there by an
    /// earlier run with more views are removed so the directory describes one run.
    pub fn commit(mut self) -> Result<Vec<PathBuf>, OutputError> {
        let files = std::mem::take(&mut self.files);
        for rel in &files {
            let dest = self.out_dir.join(rel);
            let io_err = |source| OutputError::Io {
                path: dest.clone(),
                source,
            };
            fs::create_dir_all(parent_dir(&dest)).map_err(io_err)?;
            fs::rename(self.stage_dir.join(rel), &dest).map_err(io_err)?;
        }
        remove_stale_views(&self.out_dir.join("views"), &files)?;
        Ok(files.iter().map(|rel| self.out_dir.join(rel)).collect())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.stage_dir);
    }
}

fn remove_stale_views(views_dir: &Path, written: &[PathBuf]) -> Result<(), OutputError> {
    let Ok(entries) = fs::read_dir(views_dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let rel = Path::new("views").join(&name);
        if is_view_file_name(&name) && !written.contains(&rel) {
            fs::remove_file(entry.path()).map_err(|source| OutputError::Io {
                path: entry.path(),
                source,
            })?;
        }
    }
    Ok(())
}

/// `view_NN.<ext>`, the names the pipeline gives views.
pub fn is_view_file_name(name: &str) -> bool {
    view_index(name).is_some()
}

/// The index in a `view_NN.<ext>` file name.
pub fn view_index(name: &str) -> Option<usize> {
    let stem = name.strip_prefix("view_")?;
    let (digits, ext) = stem.split_once('.')?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || ext.contains('.') {
        return None;
    }
    FileFormat::from_path(Path::new(name))?;
    digits.parse().ok()
}

pub fn view_file_name(index: usize) -> String {
    format!("view_{index:02}.png")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"two");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn dropped_staging_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        {
            let mut staging = Staging::new(&out).unwrap();
            staging.write("views/view_00.png", b"x").unwrap();
        }
        assert!(!out.exists());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn commit_moves_files_and_drops_stale_views() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        fs::create_dir_all(out.join("views")).unwrap();
        fs::write(out.join("views/view_07.png"), b"old").unwrap();
        fs::write(out.join("views/notes.txt"), b"keep").unwrap();
        let mut staging = Staging::new(&out).unwrap();
        staging.write("views/view_00.png", b"new").unwrap();
        staging.write("run.json", b"{}").unwrap();
        let files = staging.commit().unwrap();
        assert_eq!(files.len(), 2);
        assert_eq!(fs::read(out.join("views/view_00.png")).unwrap(), b"new");
        assert!(!out.join("views/view_07.png").exists());
        assert!(out.join("views/notes.txt").exists());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn view_names_parse() {
        assert_eq!(view_index("view_07.png"), Some(7));
        assert_eq!(view_index("view_123.exr"), Some(123));
        assert_eq!(view_index("view_.png"), None);
        assert_eq!(view_index("view_01.png.bak"), None);
        assert_eq!(view_index("view_01.txt"), None);
    }
}
