//! Writing results: every file goes to a temporary name in its destination directory and
//! is renamed into place, and a multi-file run is staged whole before anything appears,
//! so a failure never leaves half-written or partial outputs behind.
//!
//! A run killed while its staged files are being moved in (SIGKILL, power loss) is
//! finished by the next run on the same directory: the staging directory holds a
//! commit list, written once everything is staged, and [`Staging::new`] first rolls any
//! abandoned commit forward (or, if it never got that far, deletes the staging
//! directory), so the destination always ends up as the old run or the new one.

use std::fs;
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use image::{ImageFormat, RgbImage};

use crate::io::npy;
use crate::io::photo::SrgbImage;

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
    #[error("cannot encode {path}: {source}")]
    EncodePng {
        path: PathBuf,
        source: png::EncodingError,
    },
    #[error("{path}: unknown output type; use one of {allowed}")]
    Extension { path: PathBuf, allowed: String },
    #[error("cannot write to {what} {path}: {reason}")]
    NotWritable {
        what: &'static str,
        path: PathBuf,
        reason: String,
    },
}

/// Checks, before any work, that a run can write the output directory `out_dir`: it is
/// a directory or can be created, and both it (if it exists) and the directory beside
/// it where the run stages its files accept a new file. Creates nothing that stays.
pub fn check_output_dir(out_dir: &Path) -> Result<(), OutputError> {
    let refuse = |reason: String| OutputError::NotWritable {
        what: "--out",
        path: out_dir.into(),
        reason,
    };
    match fs::metadata(out_dir) {
        Ok(meta) if !meta.is_dir() => {
            return Err(refuse("it exists and is not a directory".into()))
        }
        Ok(_) => probe(out_dir).map_err(refuse)?,
        Err(_) => {}
    }
    probe(&nearest_existing(&parent_dir(out_dir))).map_err(refuse)
}

/// Checks, before any work, that `path` can be written: its directory exists and
/// accepts a new file, and `path` is not a directory.
pub fn check_output_file(path: &Path) -> Result<(), OutputError> {
    let refuse = |reason: String| OutputError::NotWritable {
        what: "--out",
        path: path.into(),
        reason,
    };
    if path.is_dir() {
        return Err(refuse("it is a directory".into()));
    }
    let dir = parent_dir(path);
    if !dir.is_dir() {
        return Err(refuse(format!(
            "its directory {} does not exist",
            dir.display()
        )));
    }
    probe(&dir).map_err(refuse)
}

/// The deepest existing ancestor of `dir` (itself if it exists).
fn nearest_existing(dir: &Path) -> PathBuf {
    let mut at = dir.to_path_buf();
    loop {
        if fs::symlink_metadata(&at).is_ok() {
            return at;
        }
        match at.parent() {
            Some(p) if !p.as_os_str().is_empty() => at = p.to_path_buf(),
            _ => return PathBuf::from("."),
        }
    }
}

/// The name of [`probe`]'s file, before the process id.
const PROBE_PREFIX: &str = ".reshader-probe.tmp-";

/// Whether a new file can be created in `dir` (created and removed at once): the test
/// that holds for root, read-only mounts and pseudo file systems alike, unlike the
/// permission bits.
fn probe(dir: &Path) -> Result<(), String> {
    if !dir.is_dir() {
        return Err(format!("{} is not a directory", dir.display()));
    }
    let path = dir.join(format!("{PROBE_PREFIX}{}", std::process::id()));
    match fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&path)
    {
        Ok(_) => {
            let _ = fs::remove_file(&path);
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(format!("{} does not accept new files ({e})", dir.display())),
    }
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
    encode_png_with_text(path, image, &[])
}

/// Encodes each image as `encode_png` does, on every core; in order.
pub fn encode_pngs(jobs: &[(PathBuf, &RgbImage)]) -> Result<Vec<Vec<u8>>, OutputError> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let per = jobs.len().div_ceil(cores).max(1);
    std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(per)
            .map(|chunk| {
                scope.spawn(move || {
                    chunk
                        .iter()
                        .map(|(path, image)| encode_png(path, image))
                        .collect::<Result<Vec<_>, _>>()
                })
            })
            .collect();
        let mut out = Vec::with_capacity(jobs.len());
        for handle in handles {
            out.extend(handle.join().expect("PNG encoding does not panic")?);
        }
        Ok(out)
    })
}

/// An 8-bit RGB PNG carrying `text` as tEXt chunks (keyword, value): settings a viewer
/// needs travel with the image even when run.json stays behind.
pub fn encode_png_with_text(
    path: &Path,
    image: &RgbImage,
    text: &[(&str, String)],
) -> Result<Vec<u8>, OutputError> {
    let err = |source| OutputError::EncodePng {
        path: path.into(),
        source,
    };
    let mut buf = Vec::new();
    let mut encoder = png::Encoder::new(&mut buf, image.width(), image.height());
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // fdeflate's fast mode: about a third of the time of the balanced level on a
    // Portrait quilt, for about twice the bytes (docs/benchmarks.md).
    encoder.set_compression(png::Compression::Fast);
    for (keyword, value) in text {
        encoder
            .add_text_chunk((*keyword).into(), value.clone())
            .map_err(err)?;
    }
    let mut writer = encoder.write_header().map_err(err)?;
    writer.write_image_data(image.as_raw()).map_err(err)?;
    writer.finish().map_err(err)?;
    Ok(buf)
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename,
/// so readers see either the old file or the complete new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    if path.file_name().is_none() {
        return Err(OutputError::Io {
            path: path.into(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name"),
        });
    }
    replace_file(path, bytes).map_err(|source| OutputError::Io {
        path: path.into(),
        source,
    })
}

/// [`write_atomic`] for callers with their own error type: the bare I/O error.
pub fn replace_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = temp_name(path);
    let result = write_and_sync(&tmp, bytes).and_then(|()| fs::rename(&tmp, path));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// A hidden name beside `path` for writing it before the rename that publishes it.
pub fn temp_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
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

/// Inside a staging directory: the relative paths of its files, one a line, written
/// (atomically) when the run starts moving them into the destination, followed by
/// `-`-prefixed lines naming the earlier run's products to remove.
const COMMIT_LIST: &str = ".commit";

/// The record of a run in its output directory; its `outputs` list the run's files.
const RUN_RECORD: &str = "run.json";

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
        recover(out_dir)?;
        let stage_dir = parent.join(format!("{}{}", staging_prefix(out_dir), std::process::id()));
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
        write_and_sync(&path, bytes).map_err(io_err)?;
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

    /// Moves every staged file into the destination and removes the products of the
    /// earlier run there that this run did not write (those its run.json lists, and
    /// view files of a run with more views), so that the directory holds exactly one
    /// run's products: a re-render with `--only panel` or another board's quilt name
    /// leaves no old sbs.png or quilt beside the new files. The removals are part of
    /// the commit list, so a commit killed half-way is finished with them.
    pub fn commit(mut self) -> Result<Vec<PathBuf>, OutputError> {
        let files = std::mem::take(&mut self.files);
        let stale = previous_products(&self.out_dir, &files);
        let list: String = files
            .iter()
            .map(|rel| format!("{}\n", rel.display()))
            .chain(stale.iter().map(|rel| format!("-{}\n", rel.display())))
            .collect();
        write_atomic(&self.stage_dir.join(COMMIT_LIST), list.as_bytes())?;
        move_staged(&self.stage_dir, &self.out_dir, &files, &stale)?;
        Ok(files.iter().map(|rel| self.out_dir.join(rel)).collect())
    }
}

/// The files the run recorded in `out_dir/run.json` lists that `written` does not
/// replace. Only plain relative paths inside the directory count: a run.json edited to
/// name `../x` or `/etc/x` removes nothing outside.
fn previous_products(out_dir: &Path, written: &[PathBuf]) -> Vec<PathBuf> {
    let Ok(bytes) = fs::read(out_dir.join(RUN_RECORD)) else {
        return Vec::new();
    };
    let Ok(record) = serde_json::from_slice::<serde_json::Value>(&bytes) else {
        return Vec::new();
    };
    let Some(outputs) = record.get("outputs").and_then(|o| o.as_array()) else {
        return Vec::new();
    };
    outputs
        .iter()
        .filter_map(|o| o.as_str())
        .map(PathBuf::from)
        .filter(|rel| {
            !rel.as_os_str().is_empty()
                && rel
                    .components()
                    .all(|c| matches!(c, std::path::Component::Normal(_)))
                && !written.contains(rel)
        })
        .collect()
}

/// Parses a commit list into the files to move in and the files to remove.
fn parse_commit_list(list: &str) -> (Vec<PathBuf>, Vec<PathBuf>) {
    let (mut moves, mut removals) = (Vec::new(), Vec::new());
    for line in list.lines().filter(|l| !l.is_empty()) {
        match line.strip_prefix('-') {
            Some(rel) => removals.push(PathBuf::from(rel)),
            None => moves.push(PathBuf::from(line)),
        }
    }
    (moves, removals)
}

/// Moves the staged `files` that are still in `stage_dir` into `out_dir` (a resumed
/// commit finds some already moved), then removes the earlier run's `stale` products
/// and the views an earlier run left.
fn move_staged(
    stage_dir: &Path,
    out_dir: &Path,
    files: &[PathBuf],
    stale: &[PathBuf],
) -> Result<(), OutputError> {
    for rel in files {
        let (src, dest) = (stage_dir.join(rel), out_dir.join(rel));
        if !src.exists() {
            continue;
        }
        let io_err = |source| OutputError::Io {
            path: dest.clone(),
            source,
        };
        fs::create_dir_all(parent_dir(&dest)).map_err(io_err)?;
        fs::rename(&src, &dest).map_err(io_err)?;
    }
    for rel in stale {
        let path = out_dir.join(rel);
        match fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(OutputError::Io { path, source: e })
            }
            _ => {}
        }
        // A folder the old run filled and this one does not use (views/ after
        // --only panel) goes too, if nothing else is in it.
        if let Some(dir) = rel.parent().filter(|d| !d.as_os_str().is_empty()) {
            let _ = fs::remove_dir(out_dir.join(dir));
        }
    }
    remove_stale_views(&out_dir.join("views"), files)
}

/// `.<out name>.staging-`, followed by the process id of the run that stages.
fn staging_prefix(out_dir: &Path) -> String {
    let name = out_dir
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    format!(".{name}.staging-")
}

/// Finishes or discards what runs killed while writing `out_dir` left behind: a staging
/// directory with a commit list is moved in (the run had staged everything), one without
/// is deleted (the destination still holds the earlier output), and so are a dead run's
/// temporary and probe files. Staging directories of live processes are left alone.
pub fn recover(out_dir: &Path) -> Result<(), OutputError> {
    let prefix = staging_prefix(out_dir);
    let Ok(entries) = fs::read_dir(parent_dir(out_dir)) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix(&prefix)
            .and_then(|p| p.parse::<i32>().ok())
        else {
            continue;
        };
        if process_alive(pid) {
            continue;
        }
        let stage_dir = entry.path();
        if let Ok(list) = fs::read_to_string(stage_dir.join(COMMIT_LIST)) {
            let (files, stale) = parse_commit_list(&list);
            log::warn!(
                "finishing the interrupted write of {} (process {pid})",
                out_dir.display()
            );
            move_staged(&stage_dir, out_dir, &files, &stale)?;
        }
        fs::remove_dir_all(&stage_dir).map_err(|source| OutputError::Io {
            path: stage_dir.clone(),
            source,
        })?;
    }
    remove_dead_temporaries(out_dir);
    remove_dead_probes(&parent_dir(out_dir));
    Ok(())
}

/// Deletes the probe files of processes killed between creating and removing one
/// ([`probe`] runs in the output's parent as well as in the output itself).
fn remove_dead_probes(dir: &Path) {
    remove_files_of_dead(dir, |name| {
        name.strip_prefix(PROBE_PREFIX)
            .and_then(|pid| pid.parse().ok())
    });
}

/// Deletes `.<name>.tmp-<pid>` files (see [`write_atomic`]) of processes that died
/// before renaming them.
fn remove_dead_temporaries(dir: &Path) {
    remove_files_of_dead(dir, |name| {
        name.strip_prefix('.')
            .and_then(|n| n.rsplit_once(".tmp-"))
            .and_then(|(_, pid)| pid.parse().ok())
    });
}

/// Deletes the files of `dir` whose name `pid_of` reads a process id from, where that
/// process no longer exists.
fn remove_files_of_dead(dir: &Path, pid_of: impl Fn(&str) -> Option<i32>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if pid_of(&name).is_some_and(|pid| !process_alive(pid)) {
            let _ = fs::remove_file(entry.path());
        }
    }
}

/// Whether a process with this id exists (our own counts: it is staging now).
fn process_alive(pid: i32) -> bool {
    if pid <= 0 {
        return false;
    }
    // SAFETY: signal 0 only checks that the process exists and may be signalled.
    let status = unsafe { libc::kill(pid, 0) };
    status == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
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
mod tests;
