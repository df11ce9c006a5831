//! run.json: what a run did, so that any output can be traced to its inputs and settings.

use std::io::Read;
use std::path::Path;
use std::time::Instant;

use sha2::{Digest, Sha256};

use crate::depth::net::StageReport;
use crate::depth::DepthReport;
use crate::io::photo::FovSource;
use crate::views::ViewRig;

#[derive(Debug, serde::Serialize)]
pub struct RunRecord {
    pub command: String,
    pub inputs: Inputs,
    pub board: Option<BoardRecord>,
    pub geometry: Geometry,
    pub views: Vec<ViewRecord>,
    pub reshade: String,
    pub relocate: String,
    pub blend: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rgbd: Option<RgbdRecord>,
    pub outputs: Vec<String>,
    pub timings_ms: Timings,
    pub versions: Versions,
}

#[derive(Debug, serde::Serialize)]
pub struct Inputs {
    pub photo: PhotoRecord,
    pub depth: DepthRecord,
    pub board_file: Option<FileRecord>,
    pub calibration: Option<FileRecord>,
}

#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct FileRecord {
    pub path: String,
    pub sha256: String,
}

#[derive(Debug, serde::Serialize)]
pub struct PhotoRecord {
    #[serde(flatten)]
    pub file: FileRecord,
    pub size: [u32; 2],
    pub hfov_deg: f64,
    pub fov_source: FovSource,
}

/// Where the depth came from. Its `source` field says which form this is: `"file"`
/// (path, sha256 and how the file was read), `"embedded"` (the container and range format
/// the photo carried) or `"network"` (model, its ONNX file with sha256, precision, engine).
#[derive(Debug, serde::Serialize)]
#[serde(untagged)]
pub enum DepthRecord {
    File(FileDepthRecord),
    Estimated(StageReport),
}

#[derive(Debug, serde::Serialize)]
pub struct FileDepthRecord {
    /// Always "file".
    pub source: &'static str,
    #[serde(flatten)]
    pub file: FileRecord,
    #[serde(flatten)]
    pub report: DepthReport,
}

#[derive(Debug, serde::Serialize)]
pub struct BoardRecord {
    pub name: String,
    pub origin: String,
    pub panel_size: [u32; 2],
    pub views: usize,
    pub quilt_grid: [u32; 2],
    pub view_size: [u32; 2],
    pub view_cone_deg: f32,
}

#[derive(Debug, serde::Serialize)]
pub struct Geometry {
    /// Camera offsets and depths are in the depth map's units.
    pub units: &'static str,
    pub focus: f64,
    pub focus_source: Setting,
    pub depthiness_source: Setting,
    pub rig: Option<ViewRig>,
    /// Scales the baseline of the cameras each view is reshaded for (1: the board's view
    /// cone), independent of the views' own parallax.
    pub shading_depthiness: Option<f64>,
    pub shading_depthiness_source: Option<Setting>,
    /// Factor that took depth and camera offsets to the reshading network's units.
    pub training_scale: f64,
}

#[derive(Clone, Copy, Debug, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Setting {
    CommandLine,
    RobustMiddleDepth,
    ParallaxBudget,
    TrainingReach,
}

/// The RGB-D image and the settings a viewer needs to show it as the panel does.
#[derive(Debug, serde::Serialize)]
pub struct RgbdRecord {
    pub file: String,
    /// Colour and depth sides, in pixels (the image is twice as wide).
    pub size: [u32; 2],
    pub focus: f64,
    pub depthiness: f64,
    pub depth_near: f64,
    pub depth_far: f64,
    pub depth_encoding: &'static str,
}

#[derive(Debug, serde::Serialize)]
pub struct ViewRecord {
    pub index: usize,
    /// Camera centre in the input camera's frame (OpenCV axes, depth-map units).
    pub camera: [f64; 3],
    /// The camera its colours were reshaded for (same frame and units).
    pub shading_camera: [f64; 3],
    /// Principal-point shift of the sheared projection relative to the unmoved view.
    pub principal_shift_px: [f64; 2],
}

#[derive(Debug, serde::Serialize)]
pub struct Versions {
    pub reshader: &'static str,
    /// interleave shares the workspace version.
    pub interleave: &'static str,
}

impl Default for Versions {
    fn default() -> Self {
        Self {
            reshader: env!("CARGO_PKG_VERSION"),
            interleave: env!("CARGO_PKG_VERSION"),
        }
    }
}

impl FileRecord {
    pub fn of(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            path: path.display().to_string(),
            sha256: sha256_file(path)?,
        })
    }
}

pub fn sha256_file(path: &Path) -> std::io::Result<String> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(crate::io::limits::not_a_regular_file(&meta));
    }
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Wall-clock time per stage, in the order stages first ran; repeated stages add up.
#[derive(Debug, Default)]
pub struct Timings {
    stages: Vec<(String, f64)>,
}

impl Timings {
    pub fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let result = f();
        self.add(stage, start.elapsed().as_secs_f64() * 1e3);
        result
    }

    pub fn add(&mut self, stage: &str, ms: f64) {
        match self.stages.iter_mut().find(|(s, _)| s == stage) {
            Some((_, total)) => *total += ms,
            None => self.stages.push((stage.into(), ms)),
        }
    }

    pub fn stages(&self) -> &[(String, f64)] {
        &self.stages
    }
}

/// A JSON object in stage order.
impl serde::Serialize for Timings {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.stages.len()))?;
        for (stage, ms) in &self.stages {
            map.serialize_entry(stage, &((ms * 1000.0).round() / 1000.0))?;
        }
        map.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_matches_known_digest() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("abc");
        std::fs::write(&path, b"abc").unwrap();
        assert_eq!(
            sha256_file(&path).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn repeated_stages_accumulate_in_first_seen_order() {
        let mut t = Timings::default();
        t.add("a", 1.0);
        t.add("b", 2.0);
        t.add("a", 3.0);
        assert_eq!(t.stages(), [("a".into(), 4.0), ("b".into(), 2.0)]);
        assert_eq!(serde_json::to_string(&t).unwrap(), r#"{"a":4.0,"b":2.0}"#);
    }
}
