//! The reshading graphs' part of a manifest: which tensors each form exchanges, the lobe
//! head's fields, and the checks of shapes, image, disparity and camera encodings.

use std::path::Path;

use super::*;

/// The tensors each reshading graph form exchanges, by name.
pub struct Signature {
    pub inputs: &'static [&'static str],
    pub outputs: &'static [&'static str],
}

pub const SKIPS: [&str; 5] = ["skip0", "skip1", "skip2", "skip3", "skip4"];

pub fn signature(task: Task) -> Option<Signature> {
    match task {
        Task::Reshade => Some(Signature {
            inputs: &["image", "disparity", "camera"],
            outputs: &["reshaded"],
        }),
        Task::ReshadeEncoder => Some(Signature {
            inputs: &["image", "disparity"],
            outputs: &["bottleneck", "skip0", "skip1", "skip2", "skip3", "skip4"],
        }),
        Task::ReshadeDecoder => Some(Signature {
            inputs: &[
                "image",
                "bottleneck",
                "skip0",
                "skip1",
                "skip2",
                "skip3",
                "skip4",
                "camera",
            ],
            outputs: &["reshaded"],
        }),
        Task::ReshadeLobes => Some(Signature {
            inputs: &["image", "disparity", "rays"],
            outputs: &["lobes"],
        }),
        Task::Depth | Task::Inpaint => None,
    }
}

/// The channels of one lobe in a `reshade-lobes` graph's output, in order.
pub const LOBE_LAYOUT: [&str; 7] = [
    "mu_x",
    "mu_y",
    "mu_z",
    "sharpness",
    "amp_r",
    "amp_g",
    "amp_b",
];
/// The channels a `lobes-slide` graph gives after its lobes: the share of the photo per
/// colour that slides as a reflected image, and how far behind the surface that image lies.
pub const SLIDE_LAYOUT: [&str; 4] = ["fraction_r", "fraction_g", "fraction_b", "rho"];
/// Lobes per pixel the training toolchain can make (NetConfig: 1..8).
pub const MAX_LOBES: u64 = 8;
/// Where the lobe head adds its change to the photo (the manifest's `domain`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LobeDomain {
    /// `photo + change`, in the display encoding.
    Display,
    /// In linear light (the photo decoded with gamma 2.2), never taking more light from a
    /// pixel than it has, and letting a highlight the photo clipped be brighter than white:
    /// model.shade_lobes with domain "linear-clamped" (head `lobes` only).
    LinearClamped,
}

impl LobeDomain {
    pub const ALL: [LobeDomain; 2] = [LobeDomain::Display, LobeDomain::LinearClamped];

    pub fn name(self) -> &'static str {
        match self {
            LobeDomain::Display => "display",
            LobeDomain::LinearClamped => "linear-clamped",
        }
    }

    /// The domain a manifest calls `name`, if the runtime has it.
    pub fn named(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|d| d.name() == name)
    }
}

/// What the runtime needs from a lobe-head manifest beyond the common fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LobeSpec {
    /// Lobes per pixel (K): the graph gives 7K channels.
    pub lobes: usize,
    /// Soft threshold of the summed change, in display units.
    pub deadzone: f32,
    /// Head `lobes-slide`: the graph also gives a sliding layer ([`SLIDE_LAYOUT`]).
    pub slide: bool,
    pub domain: LobeDomain,
}

impl LobeSpec {
    pub fn channels(&self) -> usize {
        LOBE_LAYOUT.len() * self.lobes + if self.slide { SLIDE_LAYOUT.len() } else { 0 }
    }

    /// The manifest's name of the head.
    pub fn head(&self) -> &'static str {
        if self.slide {
            "lobes-slide"
        } else {
            "lobes"
        }
    }
}

/// Checks the lobe head's fields of a `reshade-lobes` manifest (the common fields are
/// [`check_reshade`]'s): head, K, the channel layout (and the output's 7K channels),
/// dead zone and domain.
pub fn lobe_spec(path: &Path, manifest: &Manifest) -> Result<LobeSpec, ManifestError> {
    let err = |field: &str, problem: String| Err(field_error(path, field, problem));
    let slide = match manifest.head.as_deref() {
        Some("lobes") => false,
        Some("lobes-slide") => true,
        Some(other) => {
            return err(
                "head",
                format!("is {other:?}; expected \"lobes\" or \"lobes-slide\""),
            )
        }
        None => {
            return err(
                "head",
                "is missing (a reshade-lobes manifest says \"lobes\" or \"lobes-slide\")".into(),
            )
        }
    };
    let k = match manifest.lobes {
        Some(k) if (1..=MAX_LOBES).contains(&k) => k as usize,
        Some(k) => return err("lobes", format!("is {k}; expected 1..={MAX_LOBES}")),
        None => return err("lobes", "is missing".into()),
    };
    match &manifest.lobe_layout {
        Some(layout) if layout.iter().map(String::as_str).eq(LOBE_LAYOUT) => {}
        Some(layout) => {
            return err(
                "lobe_layout",
                format!("is {layout:?}; the runtime reads {LOBE_LAYOUT:?}"),
            )
        }
        None => return err("lobe_layout", "is missing".into()),
    }
    if let Some(channels) = &manifest.channels {
        let mut expected: Vec<String> = (0..k)
            .flat_map(|j| LOBE_LAYOUT.iter().map(move |n| format!("{n}{j}")))
            .collect();
        if slide {
            expected.extend(SLIDE_LAYOUT.iter().map(|n| n.to_string()));
        }
        if *channels != expected {
            return err(
                "channels",
                format!(
                    "are {channels:?}; head {:?} with {k} lobes gives {expected:?}",
                    manifest.head.as_deref().unwrap_or_default()
                ),
            );
        }
    }
    let deadzone = match manifest.deadzone {
        Some(t) if (0.0..0.5).contains(&t) => t as f32,
        Some(t) => return err("deadzone", format!("is {t}; expected 0 <= deadzone < 0.5")),
        None => return err("deadzone", "is missing".into()),
    };
    let domain = match manifest.domain.as_deref() {
        Some(name) => match LobeDomain::named(name) {
            Some(LobeDomain::LinearClamped) if slide => {
                return err(
                    "domain",
                    "is \"linear-clamped\", which is for head \"lobes\", not \"lobes-slide\""
                        .into(),
                )
            }
            Some(d) => d,
            None => {
                let names: Vec<_> = LobeDomain::ALL.iter().map(|d| d.name()).collect();
                return err("domain", format!("is {name:?}; expected one of {names:?}"));
            }
        },
        None => return err("domain", "is missing".into()),
    };
    if let Some(d) = manifest.disparity_depth {
        if d != 0.25 {
            return err(
                "disparity_depth",
                format!("is {d}; the runtime feeds clamp(0.25/depth, 0, 1)"),
            );
        }
    }
    let spec = LobeSpec {
        lobes: k,
        deadzone,
        slide,
        domain,
    };
    let (i, out) = manifest
        .outputs
        .iter()
        .enumerate()
        .find(|(_, t)| t.name == "lobes")
        .expect("check_reshade checked the output names");
    if out.shape.get(1) != Some(&Dim::Fixed(spec.channels() as u64)) {
        return err(
            &format!("outputs[{i}].shape"),
            format!(
                "of \"lobes\" has {} channels; head {:?} with {k} lobes (field `lobes`) needs {}",
                out.shape.get(1).map_or("no".into(), Dim::to_string),
                spec.head(),
                spec.channels()
            ),
        );
    }
    Ok(spec)
}

/// Checks that a manifest describes a reshading graph of `task` at `precision` whose
/// inputs mean what the runtime will feed them.
pub fn check_reshade(
    path: &Path,
    manifest: &Manifest,
    task: Task,
    precision: Precision,
) -> Result<(), ManifestError> {
    let err = |field: &str, problem: String| Err(field_error(path, field, problem));
    if manifest.task != task {
        return err(
            "task",
            format!(
                "is {:?}; expected {:?}",
                manifest.task.to_string(),
                task.to_string()
            ),
        );
    }
    if manifest.precision != precision {
        return err(
            "precision",
            format!(
                "is {:?} but {:?} was asked for",
                manifest.precision.to_string(),
                precision.to_string()
            ),
        );
    }
    let multiple = manifest.size_multiple;
    if multiple == 0 || !multiple.is_power_of_two() || multiple > 256 {
        return err(
            "size_multiple",
            format!("is {multiple}; expected a power of two up to 256"),
        );
    }
    let sig = signature(task).expect("reshade tasks have a signature");
    check_names(path, "inputs", &manifest.inputs, sig.inputs)?;
    check_names(path, "outputs", &manifest.outputs, sig.outputs)?;
    for (i, t) in manifest.inputs.iter().enumerate() {
        check_tensor(path, &format!("inputs[{i}]"), t)?;
    }
    for (i, t) in manifest.outputs.iter().enumerate() {
        check_tensor(path, &format!("outputs[{i}]"), t)?;
    }
    check_image(path, manifest.image.as_ref())?;
    if task != Task::ReshadeDecoder {
        check_disparity(path, manifest.disparity_encoding.as_ref())?;
    }
    if task != Task::ReshadeEncoder {
        check_camera(path, manifest.camera.as_ref())?;
    }
    if task == Task::ReshadeLobes {
        lobe_spec(path, manifest)?;
    }
    Ok(())
}

fn check_names(
    path: &Path,
    field: &str,
    specs: &[TensorSpec],
    expected: &[&str],
) -> Result<(), ManifestError> {
    let mut have: Vec<&str> = specs.iter().map(|t| t.name.as_str()).collect();
    let mut want = expected.to_vec();
    have.sort_unstable();
    want.sort_unstable();
    if have != want {
        let names: Vec<&str> = specs.iter().map(|t| t.name.as_str()).collect();
        return Err(field_error(
            path,
            field,
            format!("names are {names:?}; expected {expected:?}"),
        ));
    }
    Ok(())
}

/// The channel count and rank every reshading tensor must have (skips and bottleneck
/// depend on the network's widths, so only their rank is fixed).
fn expected_shape(name: &str) -> (&'static str, usize, Option<u64>) {
    match name {
        "image" | "reshaded" | "rays" => ("NCHW", 4, Some(3)),
        "disparity" => ("NCHW", 4, Some(1)),
        "camera" => ("NC", 2, Some(3)),
        _ => ("NCHW", 4, None),
    }
}

fn check_tensor(path: &Path, field: &str, t: &TensorSpec) -> Result<(), ManifestError> {
    let err =
        |sub: &str, problem: String| Err(field_error(path, &format!("{field}.{sub}"), problem));
    if t.dtype != "float32" {
        return err(
            "dtype",
            format!(
                "of {:?} is {:?}; the runtime feeds float32",
                t.name, t.dtype
            ),
        );
    }
    let (layout, rank, channels) = expected_shape(&t.name);
    if t.layout != layout {
        return err(
            "layout",
            format!("of {:?} is {:?}; expected {layout:?}", t.name, t.layout),
        );
    }
    if t.shape.len() != rank || t.shape.first() != Some(&Dim::Fixed(1)) {
        return err(
            "shape",
            format!(
                "of {:?} is {}; expected {rank} axes with batch 1",
                t.name,
                shape_text(&t.shape)
            ),
        );
    }
    if let Some(c) = channels {
        if t.shape[1] != Dim::Fixed(c) {
            return err(
                "shape",
                format!("of {:?} has {} channels; expected {c}", t.name, t.shape[1]),
            );
        }
    }
    Ok(())
}

fn check_image(path: &Path, image: Option<&ImageSpec>) -> Result<(), ManifestError> {
    let Some(image) = image else {
        return Err(field_error(path, "image", "is missing"));
    };
    let err = |field: &str, problem: String| Err(field_error(path, field, problem));
    if image.color != "srgb" {
        return err(
            "image.color",
            format!("is {:?}; expected \"srgb\"", image.color),
        );
    }
    if image.range != [0.0, 1.0] {
        return err(
            "image.range",
            format!("is {:?}; expected [0, 1]", image.range),
        );
    }
    if image.channel_order != "rgb" {
        return err(
            "image.channel_order",
            format!("is {:?}; expected \"rgb\"", image.channel_order),
        );
    }
    if image.mean.is_some() || image.std.is_some() {
        return err(
            "image.mean",
            "must be null: the runtime feeds unnormalised sRGB values".into(),
        );
    }
    Ok(())
}

fn check_disparity(path: &Path, enc: Option<&DisparityEncoding>) -> Result<(), ManifestError> {
    let Some(enc) = enc else {
        return Err(field_error(path, "disparity_encoding", "is missing"));
    };
    let err = |field: &str, problem: String| Err(field_error(path, field, problem));
    if enc.formula.replace(' ', "") != DISPARITY_FORMULA.replace(' ', "") {
        return err(
            "disparity_encoding.formula",
            format!(
                "is {:?}; the runtime computes {DISPARITY_FORMULA:?}",
                enc.formula
            ),
        );
    }
    if enc.frequencies != DISPARITY_FREQUENCIES {
        return err(
            "disparity_encoding.frequencies",
            format!("is {}; expected {DISPARITY_FREQUENCIES}", enc.frequencies),
        );
    }
    if enc.pi {
        return err(
            "disparity_encoding.pi",
            "is true; the contract's encoding has no factor pi".into(),
        );
    }
    if !enc.in_graph {
        return err(
            "disparity_encoding.in_graph",
            "is false; the runtime feeds d only and needs the encoding inside the graph".into(),
        );
    }
    Ok(())
}

fn check_camera(path: &Path, camera: Option<&CameraSpec>) -> Result<(), ManifestError> {
    let Some(camera) = camera else {
        return Err(field_error(path, "camera", "is missing"));
    };
    if camera.convention != CAMERA_CONVENTION {
        return Err(field_error(
            path,
            "camera.convention",
            format!(
                "is {:?}; the runtime gives camera positions in the {CAMERA_CONVENTION:?} frame",
                camera.convention
            ),
        ));
    }
    let [lo, hi] = camera.training_offset_range;
    if !(lo >= 0.0 && hi > lo) {
        return Err(field_error(
            path,
            "camera.training_offset_range",
            format!(
                "is {:?}; expected 0 <= lo < hi",
                camera.training_offset_range
            ),
        ));
    }
    Ok(())
}
