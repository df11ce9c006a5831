//! Gallery hooks: converting a batch of photos (`reshader convert`) and every photo that
//! lands in a folder (`reshader watch`, [`watch`]).
//!
//! The conversion itself is a [`Converter`] built once per process (so models load once)
//! and called per photo. Around it this module decides where each photo's outputs go,
//! skips photos already converted with the same settings, isolates failures so one bad
//! photo never stops the batch, and reports one [`PhotoReport`] per photo.
//!
//! "Already converted" is recorded by a done-marker, `.reshader-done.json`, written
//! atomically into the output directory after the converter's outputs are in place and
//! removed before a reconversion starts: a crash at any point leaves either no marker
//! (the photo is redone) or a marker describing complete outputs. It holds the photo's
//! sha256 and the converter's settings fingerprint, so an edited photo or a different
//! board is converted again.

pub mod photos;
pub mod render;
pub mod watch;

use std::collections::BTreeMap;
use std::fmt;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::io::record::sha256_file;

/// Name of the done-marker inside each output directory.
pub const DONE_MARKER: &str = ".reshader-done.json";

/// Suffix of the output directory placed beside a photo: `IMG_1.jpg` → `IMG_1.reshader/`.
pub const BESIDE_SUFFIX: &str = ".reshader";

/// What a successful conversion produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConvertReport {
    pub outputs: Vec<PathBuf>,
    pub timings_ms: BTreeMap<String, f64>,
}

/// Why a photo's conversion failed: the converter's own error, its sources kept.
pub type ConvertError = Box<dyn std::error::Error + Send + Sync>;

/// Turns one photo into outputs inside `out_dir`, writing them atomically.
pub trait Converter {
    /// Describes every setting that changes the outputs (board, products, …); a photo
    /// converted under another fingerprint is converted again.
    fn fingerprint(&self) -> String;
    /// The files besides the photo whose content the conversion of `photo` reads (its
    /// depth sidecar): an edited, added or removed one converts the photo again.
    fn inputs(&self, _photo: &Path) -> Vec<PathBuf> {
        Vec::new()
    }
    fn convert(&self, photo: &Path, out_dir: &Path) -> Result<ConvertReport, ConvertError>;
}

/// A [`Converter`] from a closure, for the CLI's pipeline and for tests.
pub struct FnConverter<F> {
    fingerprint: String,
    convert: F,
    inputs: fn(&Path) -> Vec<PathBuf>,
}

impl<F, E> FnConverter<F>
where
    F: Fn(&Path, &Path) -> Result<ConvertReport, E>,
    E: Into<ConvertError>,
{
    pub fn new(fingerprint: impl Into<String>, convert: F) -> Self {
        Self {
            fingerprint: fingerprint.into(),
            convert,
            inputs: |_| Vec::new(),
        }
    }

    /// The other files a photo's conversion reads (see [`Converter::inputs`]).
    pub fn with_inputs(mut self, inputs: fn(&Path) -> Vec<PathBuf>) -> Self {
        self.inputs = inputs;
        self
    }
}

impl<F, E> Converter for FnConverter<F>
where
    F: Fn(&Path, &Path) -> Result<ConvertReport, E>,
    E: Into<ConvertError>,
{
    fn fingerprint(&self) -> String {
        self.fingerprint.clone()
    }

    fn inputs(&self, photo: &Path) -> Vec<PathBuf> {
        (self.inputs)(photo)
    }

    fn convert(&self, photo: &Path, out_dir: &Path) -> Result<ConvertReport, ConvertError> {
        (self.convert)(photo, out_dir).map_err(Into::into)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Converted,
    /// Outputs from an earlier run match the photo and settings.
    Skipped,
    Failed,
}

/// One photo's outcome: the JSON line `--json` prints.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PhotoReport {
    pub photo: PathBuf,
    pub status: Status,
    pub out_dir: PathBuf,
    pub outputs: Vec<PathBuf>,
    pub timings_ms: BTreeMap<String, f64>,
    pub error: Option<String>,
}

impl PhotoReport {
    fn failed(photo: &Path, out_dir: &Path, error: String, total_ms: f64) -> Self {
        Self {
            photo: photo.into(),
            status: Status::Failed,
            out_dir: out_dir.into(),
            outputs: Vec::new(),
            timings_ms: BTreeMap::from([("total".into(), total_ms)]),
            error: Some(error),
        }
    }

    pub fn json_line(&self) -> String {
        serde_json::to_string(self).expect("report serialises")
    }
}

impl fmt::Display for PhotoReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let total = self.timings_ms.get("total").copied().unwrap_or(0.0);
        match self.status {
            Status::Converted => write!(
                f,
                "converted {} → {} ({total:.0} ms)",
                self.photo.display(),
                self.out_dir.display()
            ),
            Status::Skipped => write!(
                f,
                "skipped {} (already converted in {})",
                self.photo.display(),
                self.out_dir.display()
            ),
            Status::Failed => write!(
                f,
                "FAILED {}: {}",
                self.photo.display(),
                self.error.as_deref().unwrap_or("unknown error")
            ),
        }
    }
}

/// Where outputs go.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OutLayout {
    /// `PHOTO_STEM.reshader/` beside each photo.
    BesidePhoto,
    /// `DIR/PHOTO_STEM/`.
    Under(PathBuf),
}

impl OutLayout {
    pub fn out_dir(&self, photo: &Path) -> PathBuf {
        let stem = photo
            .file_stem()
            .map_or_else(|| "photo".into(), |s| s.to_string_lossy().into_owned());
        match self {
            OutLayout::BesidePhoto => photo.with_file_name(format!("{stem}{BESIDE_SUFFIX}")),
            OutLayout::Under(dir) => dir.join(stem),
        }
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Summary {
    pub converted: usize,
    pub skipped: usize,
    pub failed: usize,
}

impl Summary {
    pub fn add(&mut self, status: Status) {
        match status {
            Status::Converted => self.converted += 1,
            Status::Skipped => self.skipped += 1,
            Status::Failed => self.failed += 1,
        }
    }

    pub fn all_ok(&self) -> bool {
        self.failed == 0
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} converted, {} skipped, {} failed",
            self.converted, self.skipped, self.failed
        )
    }
}

/// The done-marker's contents.
#[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct DoneMarker {
    photo: String,
    sha256: String,
    /// sha256 of every other input by file name (the depth sidecar); markers written
    /// before this field existed read as none.
    #[serde(default)]
    inputs: BTreeMap<String, String>,
    fingerprint: String,
    /// Output paths relative to the output directory.
    outputs: Vec<PathBuf>,
}

/// Converts every photo in order, calling `emit` after each, and never stops early: a
/// photo whose output directory another photo of the batch already claimed fails alone.
pub fn convert_batch(
    photos: &[PathBuf],
    layout: &OutLayout,
    force: bool,
    converter: &dyn Converter,
    mut emit: impl FnMut(&PhotoReport),
) -> Summary {
    let mut summary = Summary::default();
    let mut claimed: BTreeMap<PathBuf, PathBuf> = BTreeMap::new();
    for photo in photos {
        let out_dir = layout.out_dir(photo);
        let report = match claimed.get(&out_dir) {
            Some(first) if first != photo => PhotoReport::failed(
                photo,
                &out_dir,
                format!(
                    "output directory {} is already used by {} in this batch; rename one \
                     of them",
                    out_dir.display(),
                    first.display()
                ),
                0.0,
            ),
            _ => {
                claimed.insert(out_dir.clone(), photo.clone());
                convert_one(photo, &out_dir, force, converter)
            }
        };
        summary.add(report.status);
        emit(&report);
    }
    summary
}

/// Converts one photo into `out_dir` unless a done-marker shows it is already converted
/// with the same photo bytes and settings (or `force`).
pub fn convert_one(
    photo: &Path,
    out_dir: &Path,
    force: bool,
    converter: &dyn Converter,
) -> PhotoReport {
    let started = Instant::now();
    let ms = |since: Instant| since.elapsed().as_secs_f64() * 1e3;
    let sha256 = match sha256_file(photo) {
        Ok(sha) => sha,
        Err(e) => {
            return PhotoReport::failed(
                photo,
                out_dir,
                format!("cannot read photo {}: {e}", photo.display()),
                ms(started),
            )
        }
    };
    let mut inputs = BTreeMap::new();
    for input in converter.inputs(photo) {
        match sha256_file(&input) {
            Ok(sha) => {
                inputs.insert(file_name(&input), sha);
            }
            Err(e) => {
                return PhotoReport::failed(
                    photo,
                    out_dir,
                    format!("cannot read {}: {e}", input.display()),
                    ms(started),
                )
            }
        }
    }
    let hash_ms = ms(started);
    let marker = DoneMarker {
        photo: file_name(photo),
        sha256,
        inputs,
        fingerprint: converter.fingerprint(),
        outputs: Vec::new(),
    };
    let marker_path = out_dir.join(DONE_MARKER);
    match read_marker(&marker_path) {
        Some(done) if done.photo != marker.photo => {
            return PhotoReport::failed(
                photo,
                out_dir,
                format!(
                    "output directory {} holds the conversion of another photo, {}; \
                     rename one of them or use --out",
                    out_dir.display(),
                    done.photo
                ),
                ms(started),
            )
        }
        Some(done) if !force && is_current(&done, &marker, out_dir) => {
            return PhotoReport {
                photo: photo.into(),
                status: Status::Skipped,
                out_dir: out_dir.into(),
                outputs: done.outputs.iter().map(|p| out_dir.join(p)).collect(),
                timings_ms: BTreeMap::from([
                    ("hash".into(), hash_ms),
                    ("total".into(), ms(started)),
                ]),
                error: None,
            };
        }
        _ => {}
    }
    if let Err(e) = remove_if_present(&marker_path) {
        return PhotoReport::failed(
            photo,
            out_dir,
            format!("cannot remove old marker {}: {e}", marker_path.display()),
            ms(started),
        );
    }
    let result = match catch_unwind(AssertUnwindSafe(|| converter.convert(photo, out_dir))) {
        Ok(result) => result,
        Err(panic)
            if crate::io::limits::is_out_of_memory(crate::io::limits::panic_text(&*panic)) =>
        {
            Err(crate::io::limits::OutOfMemory::now(format!(
                " while converting {}",
                photo.display()
            ))
            .to_string()
            .into())
        }
        Err(panic) => Err(format!(
            "internal error while converting {}: {}",
            photo.display(),
            panic_message(&*panic)
        )
        .into()),
    };
    let report = match result.and_then(|r| publish_marker(marker, out_dir, &marker_path, r)) {
        Ok(report) => report,
        Err(e) => return PhotoReport::failed(photo, out_dir, e.to_string(), ms(started)),
    };
    let mut timings_ms = report.timings_ms;
    timings_ms.insert("hash".into(), hash_ms);
    timings_ms.insert("total".into(), ms(started));
    PhotoReport {
        photo: photo.into(),
        status: Status::Converted,
        out_dir: out_dir.into(),
        outputs: report.outputs,
        timings_ms,
        error: None,
    }
}

fn publish_marker(
    mut marker: DoneMarker,
    out_dir: &Path,
    marker_path: &Path,
    report: ConvertReport,
) -> Result<ConvertReport, ConvertError> {
    marker.outputs = report
        .outputs
        .iter()
        .map(|p| p.strip_prefix(out_dir).unwrap_or(p).to_path_buf())
        .collect();
    let json = serde_json::to_vec_pretty(&marker).expect("marker serialises");
    crate::io::output::replace_file(marker_path, &json)
        .map_err(|e| format!("cannot write {}: {e}", marker_path.display()))?;
    Ok(report)
}

fn is_current(done: &DoneMarker, wanted: &DoneMarker, out_dir: &Path) -> bool {
    done.sha256 == wanted.sha256
        && done.inputs == wanted.inputs
        && done.fingerprint == wanted.fingerprint
        && done.outputs.iter().all(|p| out_dir.join(p).exists())
}

/// A marker that cannot be read or parsed counts as absent: the photo is redone.
fn read_marker(path: &Path) -> Option<DoneMarker> {
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
    let bytes = std::fs::read(path).ok()?;
    serde_json::from_slice(&bytes).ok()
}

fn remove_if_present(path: &Path) -> std::io::Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
}

fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

#[cfg(test)]
mod tests;
