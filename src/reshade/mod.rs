//! Reshading: the photo's colours as they would be shaded for another viewpoint, still
//! in the input camera's frame (relocation moves them afterwards).
//!
//! The paper's network splits into a view-independent encoder (image + disparity) and
//! a decoder that takes the camera; [`Reshader::prepare`] is the encoder's place (once per
//! photo) and [`PreparedPhoto::reshade`] the decoder's (once per view).

pub mod net;

use crate::depth::DepthMap;
use crate::io::photo::SrgbImage;
use crate::views::Intrinsics;

/// The depth at which the network's training scenes put their subjects' middle; each
/// photo is rescaled so that its focus depth lands here before reshading (geometry is
/// scale-covariant: depth ×s with offsets ×s is the same picture).
pub const TRAINING_FOCUS: f64 = 2.0;

/// The farthest the training data's novel cameras stand from the input camera (its
/// renderer's default shell, 0.1 to 0.3 units): the default shading cameras stay within it.
pub const TRAINING_REACH: f64 = 0.3;

#[derive(Debug, thiserror::Error)]
pub enum ReshadeError {
    /// The model's own error (a network reshader's `NetError`), its sources kept.
    #[error("reshading model failed: {0}")]
    Model(#[source] Box<dyn std::error::Error + Send + Sync>),
}

pub trait Reshader {
    /// What run.json records under "reshade".
    fn description(&self) -> String;

    /// View-independent work, run once per photo. `depth` is in training units (see
    /// [`TrainingFrame`]); `camera` is the camera that took `image` (its intrinsics at
    /// `image`'s size), which the lobe head needs for each pixel's ray.
    fn prepare<'a>(
        &'a self,
        image: &'a SrgbImage,
        depth: &'a DepthMap,
        camera: &Intrinsics,
    ) -> Result<Box<dyn PreparedPhoto + 'a>, ReshadeError>;
}

pub trait PreparedPhoto {
    /// The photo reshaded for a camera at `centre` (input camera frame, training units).
    fn reshade(&self, centre: [f64; 3]) -> Result<SrgbImage, ReshadeError>;

    /// The photo reshaded for every camera, in order, each view made when it is pulled:
    /// a caller that is done with each view before it pulls the next holds only a few.
    /// Given all views at once, a network can run only some of them and interpolate the
    /// rest (`--key-views`).
    fn reshade_each<'s>(
        &'s self,
        centres: &'s [[f64; 3]],
    ) -> Box<dyn Iterator<Item = Result<SrgbImage, ReshadeError>> + 's> {
        Box::new(centres.iter().map(|&c| self.reshade(c)))
    }

    /// The photo reshaded for every camera, in order, all held at once.
    fn reshade_all(&self, centres: &[[f64; 3]]) -> Result<Vec<SrgbImage>, ReshadeError> {
        self.reshade_each(centres).collect()
    }
}

/// Stands in until a reshading model is loaded: returns the photo unchanged. Whoever
/// chooses it says so once (`ReshadeArgs::build` warns), not once per photo.
#[derive(Clone, Copy, Debug, Default)]
pub struct IdentityReshader;

struct Unchanged<'a>(&'a SrgbImage);

impl Reshader for IdentityReshader {
    fn description(&self) -> String {
        "identity (no model)".into()
    }

    fn prepare<'a>(
        &'a self,
        image: &'a SrgbImage,
        _depth: &'a DepthMap,
        _camera: &Intrinsics,
    ) -> Result<Box<dyn PreparedPhoto + 'a>, ReshadeError> {
        Ok(Box::new(Unchanged(image)))
    }
}

impl PreparedPhoto for Unchanged<'_> {
    fn reshade(&self, _centre: [f64; 3]) -> Result<SrgbImage, ReshadeError> {
        Ok(self.0.clone())
    }
}

/// The scale change that takes a photo's depth units to the training data's.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TrainingFrame {
    pub scale: f64,
}

impl TrainingFrame {
    pub fn for_focus(focus: f64) -> Self {
        Self {
            scale: TRAINING_FOCUS / focus,
        }
    }

    pub fn depth(&self, depth: &DepthMap) -> DepthMap {
        depth.scaled(self.scale as f32)
    }

    pub fn camera(&self, centre: [f64; 3]) -> [f64; 3] {
        centre.map(|c| c * self.scale)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_returns_the_photo_for_any_camera() {
        let mut img = SrgbImage::new(3, 2);
        img.put(1, 1, [0.2, 0.4, 0.6]);
        let depth = DepthMap::new(3, 2, vec![1.0; 6]);
        let reshader = IdentityReshader;
        let camera = Intrinsics::from_hfov(3, 2, 60.0);
        let prepared = reshader.prepare(&img, &depth, &camera).unwrap();
        assert_eq!(prepared.reshade([0.3, 0.0, 0.0]).unwrap(), img);
        assert_eq!(reshader.description(), "identity (no model)");
    }

    #[test]
    fn training_frame_puts_focus_at_training_depth() {
        let frame = TrainingFrame::for_focus(8.0);
        let depth = frame.depth(&DepthMap::new(1, 1, vec![8.0]));
        assert!((f64::from(depth.at(0, 0)) - TRAINING_FOCUS).abs() < 1e-6);
        assert_eq!(frame.camera([4.0, 0.0, -8.0]), [1.0, 0.0, -2.0]);
    }
}
