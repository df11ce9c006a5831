//! View filtering: how much of which views a subpixel shows, given where it sits in the
//! view cone.
//!
//! A subpixel at cone position `t ∈ [0, 1]` lies between view centres: view `i` is
//! centred at `(i + 0.5)/N`. Nearest takes the one view, linear mixes the two bracketing
//! centres, and Gaussian weighs the three nearest views by `exp(−d²/2σ²)`, `d` the
//! distance from the subpixel to the view's centre in views. None of them mixes across
//! the cone's wrap (the two most different views). Dimming darkens subpixels towards
//! both ends of the cone, where the view jumps from the last to the first, so that the
//! jump is seen as a dark seam instead of a double image.

use std::fmt;
use std::str::FromStr;

use serde::Deserialize;

use crate::mapping::{blend_views, nearest_view};

/// The Gaussian's width in views, when a board does not give one.
pub const DEFAULT_SIGMA: f64 = 0.5;
/// Accepted Gaussian widths, in views: below it the blend is nearest; above it the three
/// taps no longer cover the Gaussian.
pub const SIGMA_RANGE: (f64, f64) = (0.1, 2.0);
/// Most of the cone that may be dimmed at each end.
pub const MAX_DIM_EDGES: f64 = 0.5;

/// How a subpixel between view centres is coloured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Blend {
    /// The one view whose slice of the cone the subpixel falls in.
    #[default]
    Nearest,
    /// A linear mix of the two views whose centres bracket the subpixel's cone position.
    Linear,
    /// The three nearest views, weighted by a Gaussian of their distance in views.
    Gaussian,
}

impl Blend {
    pub fn name(self) -> &'static str {
        match self {
            Blend::Nearest => "nearest",
            Blend::Linear => "linear",
            Blend::Gaussian => "gaussian",
        }
    }
}

impl fmt::Display for Blend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A blend name that is none of `nearest`, `linear`, `gaussian`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown blend mode `{0}`; use `nearest`, `linear` or `gaussian`")]
pub struct UnknownBlend(pub String);

impl FromStr for Blend {
    type Err = UnknownBlend;

    fn from_str(s: &str) -> Result<Blend, UnknownBlend> {
        match s {
            "nearest" => Ok(Blend::Nearest),
            "linear" | "blend" => Ok(Blend::Linear),
            "gaussian" => Ok(Blend::Gaussian),
            other => Err(UnknownBlend(other.to_string())),
        }
    }
}

/// A board's view filtering: the blend, the Gaussian's width, and edge dimming.
///
/// In a board file, the optional `[filter]` table: `blend`, `sigma`, `dim_edges`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewFilter {
    pub blend: Blend,
    /// Standard deviation of the Gaussian blend, in views.
    pub sigma: f64,
    /// Fraction of the cone, at each end, over which brightness falls to black at the
    /// very edge (smoothstep); 0 turns dimming off.
    pub dim_edges: f64,
}

impl Default for ViewFilter {
    fn default() -> ViewFilter {
        ViewFilter {
            blend: Blend::Nearest,
            sigma: DEFAULT_SIGMA,
            dim_edges: 0.0,
        }
    }
}

impl From<Blend> for ViewFilter {
    fn from(blend: Blend) -> ViewFilter {
        ViewFilter {
            blend,
            ..ViewFilter::default()
        }
    }
}

/// Up to three consecutive views from `first`, and their weights (summing to the
/// dimming factor, at most 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Taps {
    pub first: usize,
    pub weights: [f64; 3],
}

impl ViewFilter {
    /// Whether weaving needs per-subpixel weights beyond nearest's and linear's tables.
    pub fn weighted(&self) -> bool {
        self.blend == Blend::Gaussian || self.dim_edges > 0.0
    }

    /// Bytes of weaving table per subpixel (the memory a weave needs grows with it).
    pub fn table_bytes_per_subpixel(&self) -> u64 {
        match (self.weighted(), self.blend) {
            (true, _) => 4,
            (false, Blend::Linear) => 3,
            (false, _) => 1,
        }
    }

    /// Brightness at cone position `t`: 1 inside, falling smoothly to 0 at both ends.
    pub fn dimming(&self, t: f64) -> f64 {
        if self.dim_edges <= 0.0 {
            return 1.0;
        }
        let x = (t.min(1.0 - t) / self.dim_edges).clamp(0.0, 1.0);
        x * x * (3.0 - 2.0 * x)
    }

    /// The views and weights a subpixel at cone position `t` shows among `views` views.
    pub fn taps(&self, t: f64, views: usize) -> Taps {
        self.tapper(views)(t)
    }

    /// [`ViewFilter::taps`] with what does not depend on `t` worked out once: the
    /// weaving table calls it for every subpixel.
    pub fn tapper(&self, views: usize) -> impl Fn(f64) -> Taps {
        let filter = *self;
        let k = 1.0 / (2.0 * self.sigma * self.sigma);
        let outer_ratio = (-2.0 * k).exp();
        move |t| {
            let dim = filter.dimming(t);
            let (first, weights) = match filter.blend {
                Blend::Nearest => (nearest_view(t, views), [1.0, 0.0, 0.0]),
                Blend::Linear => {
                    let (v, w) = blend_views(t, views);
                    (v, [1.0 - w, w, 0.0])
                }
                Blend::Gaussian => gaussian(t, views, k, outer_ratio),
            };
            Taps {
                first,
                weights: weights.map(|w| w * dim),
            }
        }
    }
}

/// The three views nearest to `t` and their Gaussian weights, normalised; `k = 1/2σ²`
/// and `outer_ratio = exp(−2k)`.
///
/// With `d` the distance from the middle tap, the outer taps weigh `exp(−(2d + 1)k)` and
/// `exp((2d − 1)k)` relative to it, and their product is `exp(−2k)`: one `exp` per
/// subpixel instead of three.
fn gaussian(t: f64, views: usize, k: f64, outer_ratio: f64) -> (usize, [f64; 3]) {
    let last = views - 1;
    // Position in view-centre units, held inside the outermost centres as linear does.
    let s = (t * views as f64 - 0.5).clamp(0.0, last as f64);
    let nearest = (s + 0.5) as usize;
    if views < 3 {
        let d = s - 1.0;
        let w = [(-s * s * k).exp(), (-d * d * k).exp()];
        let total = w[0] + w[1];
        return (0, [w[0] / total, w[1] / total, 0.0]);
    }
    let first = nearest.saturating_sub(1).min(views - 3);
    let d = s - (first + 1) as f64;
    let below = (-(2.0 * d + 1.0) * k).exp();
    let above = outer_ratio / below;
    let total = below + 1.0 + above;
    (first, [below / total, 1.0 / total, above / total])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian(sigma: f64) -> ViewFilter {
        ViewFilter {
            blend: Blend::Gaussian,
            sigma,
            dim_edges: 0.0,
        }
    }

    #[test]
    fn gaussian_weights_by_hand() {
        // 10 views, t at the centre of view 4 (t = 4.5/10): taps 3, 4, 5 at distances
        // 1, 0, 1. With σ = 0.5: exp(−1/0.5) = e^−2 = 0.135335, so the weights are
        // 0.135335, 1, 0.135335 over 1.270671: 0.106507, 0.786986, 0.106507.
        let taps = gaussian(0.5).taps(0.45, 10);
        assert_eq!(taps.first, 3);
        let expect = [0.106507, 0.786986, 0.106507];
        for (w, e) in taps.weights.iter().zip(expect) {
            assert!((w - e).abs() < 1e-6, "{:?}", taps.weights);
        }
        // Halfway between the centres of views 4 and 5 (t = 0.5, s = 4.5): nearest is 5,
        // taps 4, 5, 6 at distances 0.5, 0.5, 1.5: e^−0.5 = 0.606531 twice and
        // e^−4.5 = 0.011109, over 1.224171: 0.495463, 0.495463, 0.009075.
        let taps = gaussian(0.5).taps(0.5, 10);
        assert_eq!(taps.first, 4);
        let expect = [0.495463, 0.495463, 0.009075];
        for (w, e) in taps.weights.iter().zip(expect) {
            assert!((w - e).abs() < 1e-6, "{:?}", taps.weights);
        }
    }

    #[test]
    fn gaussian_stays_inside_the_cone() {
        // Beyond the outermost centres the position is held at them: view 0's centre,
        // taps 0, 1, 2 at distances 0, 1, 2.
        let low = gaussian(0.5).taps(0.0, 10);
        assert_eq!(low.first, 0);
        assert!(low.weights[0] > low.weights[1] && low.weights[1] > low.weights[2]);
        let high = gaussian(0.5).taps(1.0, 10);
        assert_eq!(high.first, 7);
        assert!(high.weights[2] > high.weights[1]);
        // Two views: two taps only.
        let two = gaussian(0.5).taps(0.5, 2);
        assert_eq!((two.first, two.weights[2]), (0, 0.0));
        assert!((two.weights[0] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn dimming_falls_to_black_at_both_ends() {
        let f = ViewFilter {
            dim_edges: 0.1,
            ..ViewFilter::default()
        };
        assert_eq!(f.dimming(0.0), 0.0);
        assert_eq!(f.dimming(1.0), 0.0);
        // Halfway into the dimmed band: smoothstep(0.5) = 0.5.
        assert!((f.dimming(0.05) - 0.5).abs() < 1e-12);
        assert!((f.dimming(0.95) - 0.5).abs() < 1e-9);
        assert_eq!(f.dimming(0.1), 1.0);
        assert_eq!(f.dimming(0.5), 1.0);
        // Weights carry the dimming: nearest at t = 0.05 shows its view at half strength.
        let w = f.taps(0.05, 10).weights;
        assert!(
            (w[0] - 0.5).abs() < 1e-12 && w[1] == 0.0 && w[2] == 0.0,
            "{w:?}"
        );
    }

    #[test]
    fn blend_names_parse() {
        assert_eq!("gaussian".parse::<Blend>(), Ok(Blend::Gaussian));
        assert_eq!(
            "cubic".parse::<Blend>().unwrap_err().to_string(),
            "unknown blend mode `cubic`; use `nearest`, `linear` or `gaussian`"
        );
    }
}
