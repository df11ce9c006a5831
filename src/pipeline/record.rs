//! run.json: what a run did, so that any output can be traced to its inputs and settings.

use crate::depth::net::StageReport;
use crate::depth::DepthReport;
use crate::io::photo::FovSource;
use crate::io::record::{FileRecord, Timings};
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
