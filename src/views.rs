//! View geometry: where each view's camera sits and how it projects.
//!
//! Cameras keep the input camera's orientation (OpenCV axes: x right, y down, z
//! forward) and move along x. Each view's projection is sheared (off-axis) so that the
//! zero-parallax plane z = focus projects exactly as in the input camera: points on it
//! do not move between views, nearer points move against the camera, farther ones with it.

use crate::depth::DepthMap;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ViewError {
    #[error("view count must be at least 1")]
    NoViews,
    #[error("view cone {0}° is outside [0°, 180°)")]
    Cone(f64),
    #[error("--depthiness {0} must be a finite number from 0 to {MAX_DEPTHINESS} (1 spans the board's view cone)")]
    Depthiness(f64),
    #[error("focus depth {0} must be a finite number > 0")]
    Focus(f64),
    #[error("camera {} is at or beyond the zero-parallax plane z = {focus}", Xyz(*.centre))]
    BeyondFocus { centre: [f64; 3], focus: f64 },
    #[error(
        "camera {} is {distance:e} units from the photo's camera, more than \
         {MAX_CAMERA_DISTANCE} times the zero-parallax depth {focus}: a view from there \
         shows nothing of the scene",
        Xyz(*.centre)
    )]
    FarCamera {
        centre: [f64; 3],
        distance: f64,
        focus: f64,
    },
}

/// The largest `--depthiness`: ten times the baseline that spans the board's view cone.
pub const MAX_DEPTHINESS: f64 = 10.0;
/// The farthest a view's camera may be from the photo's, in zero-parallax depths.
pub const MAX_CAMERA_DISTANCE: f64 = 1e4;

/// A camera position as `(x, y, z)` for messages.
struct Xyz([f64; 3]);

impl std::fmt::Display for Xyz {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let short = |v: f64| {
            if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
                format!("{v:e}")
            } else {
                format!("{v}")
            }
        };
        let [x, y, z] = self.0.map(short);
        write!(f, "({x}, {y}, {z})")
    }
}

/// Checks a `--depthiness` before any work (see [`ViewRig::new`]).
pub fn check_depthiness(depthiness: f64) -> Result<(), ViewError> {
    if depthiness.is_finite() && (0.0..=MAX_DEPTHINESS).contains(&depthiness) {
        Ok(())
    } else {
        Err(ViewError::Depthiness(depthiness))
    }
}

/// Pinhole intrinsics in pixels. Pixel (i, j) covers [i, i+1) × [j, j+1); its centre is
/// at (i + 0.5, j + 0.5).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Square pixels, principal point at the image centre.
    pub fn from_hfov(width: u32, height: u32, hfov_deg: f64) -> Self {
        let f = f64::from(width) / 2.0 / (hfov_deg.to_radians() / 2.0).tan();
        Self {
            fx: f,
            fy: f,
            cx: f64::from(width) / 2.0,
            cy: f64::from(height) / 2.0,
            width,
            height,
        }
    }

    /// The same camera at another resolution: scaled to cover `width`×`height` and
    /// centre-cropped, as a photo is fitted to a view of another aspect.
    pub fn cover(&self, width: u32, height: u32) -> Self {
        let s = (f64::from(width) / f64::from(self.width))
            .max(f64::from(height) / f64::from(self.height));
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: self.cx * s - (f64::from(self.width) * s - f64::from(width)) / 2.0,
            cy: self.cy * s - (f64::from(self.height) * s - f64::from(height)) / 2.0,
            width,
            height,
        }
    }

    /// The camera-frame point at pixel position (u, v) and depth z.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> [f64; 3] {
        [(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z]
    }

    /// Pixel position of a camera-frame point in front of the camera.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        [
            self.fx * p[0] / p[2] + self.cx,
            self.fy * p[1] / p[2] + self.cy,
        ]
    }
}

/// One view's camera: its centre in the input camera's frame and its (sheared)
/// intrinsics. Orientation is the input camera's.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ViewCamera {
    pub centre: [f64; 3],
    pub intrinsics: Intrinsics,
}

impl ViewCamera {
    /// The off-axis camera at `centre` whose image of the plane z = `focus` is the
    /// `reference` camera's image of it. Derivation: for (X, Y, F) the view sees
    /// u' = fx'(X − tx)/(F − tz) + cx'; u' = fx X/F + cx for all X needs
    /// fx' = fx (F − tz)/F and cx' = cx + fx tx/F (likewise for y).
    pub fn off_axis(
        reference: &Intrinsics,
        centre: [f64; 3],
        focus: f64,
    ) -> Result<Self, ViewError> {
        if !(focus.is_finite() && focus > 0.0) {
            return Err(ViewError::Focus(focus));
        }
        if centre[2] >= focus {
            return Err(ViewError::BeyondFocus { centre, focus });
        }
        let distance = centre[0].hypot(centre[1]).hypot(centre[2]);
        if distance.is_nan() || distance > MAX_CAMERA_DISTANCE * focus {
            return Err(ViewError::FarCamera {
                centre,
                distance,
                focus,
            });
        }
        let zoom = (focus - centre[2]) / focus;
        Ok(Self {
            centre,
            intrinsics: Intrinsics {
                fx: reference.fx * zoom,
                fy: reference.fy * zoom,
                cx: reference.cx + reference.fx * centre[0] / focus,
                cy: reference.cy + reference.fy * centre[1] / focus,
                ..*reference
            },
        })
    }

    /// Pixel position and view-space depth of a point given in the input camera's
    /// frame; `None` behind (or at) the camera.
    pub fn project(&self, p: [f64; 3]) -> Option<([f64; 2], f64)> {
        let q = [
            p[0] - self.centre[0],
            p[1] - self.centre[1],
            p[2] - self.centre[2],
        ];
        (q[2] > 1e-9).then(|| (self.intrinsics.project(q), q[2]))
    }
}

/// With automatic depthiness, the largest shift (fraction of the view width) that a
/// point between the scene's near and far depths makes in the outermost views. A full
/// view cone applied to a photographed scene gives parallax of tens of percent, far more
/// than a panel's depth of field shows sharply or one photo has background for.
pub const PARALLAX_BUDGET: f64 = 0.03;

/// How a board's views are laid out around the photo's camera.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ViewRig {
    pub count: usize,
    pub cone_deg: f64,
    pub focus: f64,
    pub depthiness: f64,
}

impl ViewRig {
    pub fn new(
        count: usize,
        cone_deg: f64,
        focus: f64,
        depthiness: f64,
    ) -> Result<Self, ViewError> {
        if count == 0 {
            return Err(ViewError::NoViews);
        }
        if !(cone_deg.is_finite() && (0.0..180.0).contains(&cone_deg)) {
            return Err(ViewError::Cone(cone_deg));
        }
        check_depthiness(depthiness)?;
        if !(focus.is_finite() && focus > 0.0) {
            return Err(ViewError::Focus(focus));
        }
        Ok(Self {
            count,
            cone_deg,
            focus,
            depthiness,
        })
    }

    /// Camera x offsets, view 0 leftmost. The outermost cameras see the focus point
    /// at ±cone/2, the angle at which the panel shows them, scaled by depthiness.
    pub fn offsets(&self) -> Vec<f64> {
        let half_baseline = self.focus * (self.cone_deg.to_radians() / 2.0).tan() * self.depthiness;
        if self.count == 1 {
            return vec![0.0];
        }
        (0..self.count)
            .map(|k| half_baseline * (2.0 * k as f64 / (self.count - 1) as f64 - 1.0))
            .collect()
    }

    /// The depthiness (at most 1) at which the outermost views shift the scene's `near`
    /// and `far` points by [`PARALLAX_BUDGET`] of the width of `reference`'s image.
    pub fn fitting_depthiness(
        cone_deg: f64,
        focus: f64,
        (near, far): (f64, f64),
        reference: &Intrinsics,
    ) -> f64 {
        let full_cone = focus * (cone_deg.to_radians() / 2.0).tan();
        let spread = (1.0 / near - 1.0 / focus)
            .abs()
            .max((1.0 / focus - 1.0 / far).abs());
        if !(full_cone > 0.0 && spread > 0.0) {
            return 1.0;
        }
        let half_baseline = PARALLAX_BUDGET * f64::from(reference.width) / (reference.fx * spread);
        (half_baseline / full_cone).min(1.0)
    }

    /// Every view's camera centre (the rig moves cameras along x only).
    pub fn centres(&self) -> Vec<[f64; 3]> {
        self.offsets().into_iter().map(|x| [x, 0.0, 0.0]).collect()
    }

    /// Every view's camera for output images whose unmoved camera is `reference`.
    pub fn cameras(&self, reference: &Intrinsics) -> Vec<ViewCamera> {
        self.offsets()
            .into_iter()
            .map(|x| {
                ViewCamera::off_axis(reference, [x, 0.0, 0.0], self.focus)
                    .expect("rig validated focus; tz = 0 is in front of it")
            })
            .collect()
    }
}

/// The default zero-parallax depth: the harmonic middle of the 5th and 95th depth
/// percentiles, i.e. the depth halfway between them in disparity, so that the nearest
/// and farthest parts of the scene get parallax of equal size and opposite sign.
pub fn robust_focus(depth: &DepthMap) -> f64 {
    let (near, far) = robust_range(depth);
    2.0 / (1.0 / near + 1.0 / far)
}

/// The scene's near and far depths: the 5th and 95th percentiles.
pub fn robust_range(depth: &DepthMap) -> (f64, f64) {
    (
        f64::from(depth.percentile(0.05)),
        f64::from(depth.percentile(0.95)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intrinsics() -> Intrinsics {
        Intrinsics::from_hfov(64, 48, 60.0)
    }

    #[test]
    fn focus_plane_points_do_not_move() {
        let k = intrinsics();
        let focus = 2.5;
        let rig = ViewRig::new(5, 40.0, focus, 1.0).unwrap();
        for (u, v) in [(0.5, 0.5), (31.0, 20.0), (63.5, 47.5)] {
            let p = k.unproject(u, v, focus);
            for cam in rig.cameras(&k) {
                let ([pu, pv], z) = cam.project(p).unwrap();
                assert!((pu - u).abs() < 1e-9 && (pv - v).abs() < 1e-9);
                assert!((z - focus).abs() < 1e-12);
            }
        }
        let moved = ViewCamera::off_axis(&k, [0.1, -0.2, 0.5], focus).unwrap();
        let ([pu, pv], _) = moved.project(k.unproject(10.0, 40.0, focus)).unwrap();
        assert!((pu - 10.0).abs() < 1e-9 && (pv - 40.0).abs() < 1e-9);
    }

    #[test]
    fn views_run_left_to_right_symmetrically() {
        let rig = ViewRig::new(48, 40.0, 2.0, 1.0).unwrap();
        let x = rig.offsets();
        assert_eq!(x.len(), 48);
        assert!(x.windows(2).all(|w| w[0] < w[1]), "view 0 is leftmost");
        for k in 0..48 {
            assert!((x[k] + x[47 - k]).abs() < 1e-12);
        }
        // Outermost views see the focus point at the cone's edges.
        assert!(((x[47] / 2.0).atan().to_degrees() - 20.0).abs() < 1e-9);
        let shallow = ViewRig::new(48, 40.0, 2.0, 0.5).unwrap().offsets();
        assert!((shallow[47] - x[47] / 2.0).abs() < 1e-12);
        assert_eq!(
            ViewRig::new(1, 40.0, 2.0, 1.0).unwrap().offsets(),
            vec![0.0]
        );
    }

    #[test]
    fn near_points_move_against_the_camera_far_points_with_it() {
        let k = intrinsics();
        let right = ViewCamera::off_axis(&k, [0.2, 0.0, 0.0], 2.0).unwrap();
        let ([near_u, _], _) = right.project(k.unproject(32.0, 24.0, 1.0)).unwrap();
        let ([far_u, _], _) = right.project(k.unproject(32.0, 24.0, 8.0)).unwrap();
        assert!(near_u < 32.0 && far_u > 32.0);
    }

    #[test]
    fn cover_crops_the_longer_side() {
        let k = Intrinsics::from_hfov(400, 300, 50.0).cover(300, 300);
        assert_eq!((k.width, k.height), (300, 300));
        assert!((k.cx - 150.0).abs() < 1e-9 && (k.cy - 150.0).abs() < 1e-9);
        // Vertical extent is kept (scale 1), so the horizontal one is cropped.
        assert!((k.fx - Intrinsics::from_hfov(400, 300, 50.0).fx).abs() < 1e-9);
    }

    #[test]
    fn invalid_rigs_are_refused() {
        assert_eq!(ViewRig::new(0, 40.0, 1.0, 1.0), Err(ViewError::NoViews));
        assert_eq!(
            ViewRig::new(2, 180.0, 1.0, 1.0),
            Err(ViewError::Cone(180.0))
        );
        assert_eq!(ViewRig::new(2, 40.0, 0.0, 1.0), Err(ViewError::Focus(0.0)));
        assert!(ViewRig::new(2, 40.0, 1.0, f64::NAN).is_err());
        assert!(ViewCamera::off_axis(&intrinsics(), [0.0, 0.0, 3.0], 2.0).is_err());
    }

    #[test]
    fn fitted_depthiness_keeps_outer_parallax_in_budget() {
        let k = Intrinsics::from_hfov(420, 560, 30.0);
        let (focus, range) = (2.0, (1.0, 5.0));
        let depthiness = ViewRig::fitting_depthiness(40.0, focus, range, &k);
        assert!(depthiness > 0.0 && depthiness < 1.0);
        let rig = ViewRig::new(48, 40.0, focus, depthiness).unwrap();
        let outer = rig.cameras(&k)[47];
        let shift = |z: f64| outer.project(k.unproject(210.0, 280.0, z)).unwrap().0[0] - 210.0;
        let budget = PARALLAX_BUDGET * 420.0;
        assert!((shift(1.0).abs().max(shift(5.0).abs()) - budget).abs() < 1e-9);
        // A flat scene needs no limit.
        assert_eq!(ViewRig::fitting_depthiness(40.0, 2.0, (2.0, 2.0), &k), 1.0);
    }

    #[test]
    fn robust_focus_is_the_disparity_middle() {
        let data: Vec<f32> = (0..100).map(|i| if i < 50 { 1.0 } else { 4.0 }).collect();
        let focus = robust_focus(&DepthMap::new(10, 10, data));
        assert!((focus - 1.6).abs() < 1e-6, "{focus}");
    }
}
