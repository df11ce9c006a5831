//! The subpixel → view mapping every board reduces to.
//!
//! A slanted lenticular sheet gives each subpixel a *phase*: how far across its lens the
//! subpixel sits, in lens widths. Within a board the phase is linear in the subpixel's
//! horizontal index `k = 3x + p` (`p` the subpixel's position inside its pixel) and in
//! its row `y` (counted from the top):
//!
//! ```text
//! phase(k, y) = a·k + b·y + d
//! t           = frac(phase)          (or 1 − frac(phase) when the view order is inverted)
//! view        = min(floor(t·N), N − 1)
//! ```
//!
//! [`LensPhase::looking_glass`] and [`LensPhase::van_berkel`] derive `a`, `b`, `d` from
//! the two usual descriptions.

use crate::cells::{CellPattern, SubpixelCell};
use crate::lens::{LookingGlass, SubpixelLayout, VanBerkel};

/// Linear lens phase `a·k + b·y + d` (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensPhase {
    /// `a`: phase step from one subpixel to the next along a row (1 / lens pitch in subpixels).
    pub per_subpixel: f64,
    /// `b`: phase step from one row to the next one down.
    pub per_row: f64,
    /// `d`: phase of subpixel 0 of the top row.
    pub offset: f64,
    /// View numbers run against the phase (`t = 1 − frac(phase)`).
    pub invert: bool,
}

impl LensPhase {
    /// Looking Glass Factory's mapping for a `w`x`h` panel.
    ///
    /// Their shader computes, with `u = (x+0.5)/W` and `v = (y_up+0.5)/H` (`y_up` counted
    /// from the bottom row):
    /// `phase_c = (u + c·subp + v·tilt)·pitch' − center`,
    /// `pitch' = pitch·(W/DPI)·cos(atan(1/slope))`, `tilt = H/(W·slope)` (negated by
    /// `flip_image_x`), `subp = 1/(3W)`. Substituting `u + c·subp = (k + 1.5)·subp` and
    /// `y_up = H − 1 − y` gives the linear form.
    pub fn looking_glass(lg: &LookingGlass, width: u32, height: u32) -> LensPhase {
        let (w, h) = (f64::from(width), f64::from(height));
        let pitch = lg.pitch * (w / lg.dpi) * (1.0 / lg.slope).atan().cos();
        let tilt = h / (w * lg.slope) * if lg.flip_image_x { -1.0 } else { 1.0 };
        let subp = 1.0 / (3.0 * w);
        LensPhase {
            per_subpixel: subp * pitch,
            per_row: -tilt * pitch / h,
            offset: 1.5 * subp * pitch + (h - 0.5) / h * tilt * pitch - lg.center,
            invert: lg.inv_view,
        }
    }

    /// Van Berkel's mapping: `t = frac((k + offset − 3·y·tan α) / X)` with `X` the lens
    /// pitch in subpixels.
    pub fn van_berkel(vb: &VanBerkel) -> LensPhase {
        let x = vb.lens_pitch;
        LensPhase {
            per_subpixel: 1.0 / x,
            per_row: -3.0 * vb.tan_alpha() / x,
            offset: vb.offset / x,
            invert: false,
        }
    }

    /// Phase of the subpixel at horizontal subpixel index `k` in row `y`.
    ///
    /// Takes reals so that periodicity can be checked between subpixel positions.
    pub fn phase(&self, k: f64, y: f64) -> f64 {
        self.per_subpixel * k + self.per_row * y + self.offset
    }

    /// Horizontal lens pitch in subpixels.
    pub fn lens_pitch_subpixels(&self) -> f64 {
        1.0 / self.per_subpixel
    }

    /// Position `t` in the view cone, in `[0, 1]`, for a phase.
    pub fn cone_position(&self, phase: f64) -> f64 {
        let f = phase - floor(phase);
        if self.invert {
            1.0 - f
        } else {
            f
        }
    }
}

/// Nearest view for a cone position `t` in `[0, 1]` among `views` views.
pub fn nearest_view(t: f64, views: usize) -> usize {
    // `as` truncates, which is floor for the non-negative t·N.
    ((t * views as f64) as usize).min(views - 1)
}

/// `f64::floor` without the libm call that baseline x86-64 (no SSE4.1) compiles it to;
/// the lookup-table build calls it once per subpixel. Exact for |x| < 2^52.
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// The two views to blend for cone position `t`, and the weight of the second.
///
/// View `i` is centred at `(i + 0.5)/N`; between two centres the neighbours are mixed
/// linearly, and beyond the outermost centres the outermost view is used alone (blending
/// across the cone's wrap would mix the two most different views).
pub fn blend_views(t: f64, views: usize) -> (usize, f64) {
    let s = t * views as f64 - 0.5;
    if s <= 0.0 {
        return (0, 0.0);
    }
    let last = views - 1;
    if s >= last as f64 {
        return (last, 0.0);
    }
    let i = s as usize;
    (i, s - i as f64)
}

#[derive(Debug, Clone, PartialEq)]
enum Kind {
    Lenticular {
        layout: SubpixelLayout,
        phase: LensPhase,
    },
    /// Subpixels at the positions their cell gives: `phase` at `k = 3x` is the pixel
    /// centre's phase, and `shifts[cell][c]` the phase from there to channel `c`.
    Cells {
        phase: LensPhase,
        pattern: CellPattern,
        shifts: Vec<[f64; 3]>,
    },
    SideBySide,
}

/// Complete subpixel → (view, source position) mapping for one board.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    width: u32,
    height: u32,
    views: usize,
    kind: Kind,
    flip_x: bool,
    flip_y: bool,
}

impl Mapping {
    /// A slanted-lenticular mapping; `flip` mirrors the image sampled from each view.
    pub fn lenticular(
        width: u32,
        height: u32,
        views: u32,
        layout: SubpixelLayout,
        phase: LensPhase,
        flip: (bool, bool),
    ) -> Mapping {
        Mapping {
            width,
            height,
            views: views as usize,
            kind: Kind::Lenticular { layout, phase },
            flip_x: flip.0,
            flip_y: flip.1,
        }
    }

    /// A slanted-lenticular mapping whose subpixels sit where `cells` put them.
    ///
    /// A subpixel `(dx, dy)` pixels from its pixel centre (dy upward) has the phase of the
    /// centre plus `pitch'·(dx/W + tilt·dy/H)`; with `a = pitch'/(3W)` and
    /// `b = −tilt·pitch'/H` (see [`LensPhase::looking_glass`]) that is `3a·dx − b·dy`.
    pub fn cells(
        width: u32,
        height: u32,
        views: u32,
        phase: LensPhase,
        pattern: CellPattern,
        cells: &[SubpixelCell],
        flip: (bool, bool),
    ) -> Mapping {
        let shifts = cells
            .iter()
            .map(|cell| {
                [0, 1, 2].map(|c| {
                    let [dx, dy] = cell.offset(c);
                    3.0 * phase.per_subpixel * dx - phase.per_row * dy
                })
            })
            .collect();
        Mapping {
            width,
            height,
            views: views as usize,
            kind: Kind::Cells {
                phase,
                pattern,
                shifts,
            },
            flip_x: flip.0,
            flip_y: flip.1,
        }
    }

    /// Two views side by side, each squeezed into half the panel width.
    pub fn side_by_side(width: u32, height: u32) -> Mapping {
        Mapping {
            width,
            height,
            views: 2,
            kind: Kind::SideBySide,
            flip_x: false,
            flip_y: false,
        }
    }

    pub fn panel_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    pub fn views(&self) -> usize {
        self.views
    }

    /// The lens phase, for lenticular boards.
    pub fn lens_phase(&self) -> Option<&LensPhase> {
        match &self.kind {
            Kind::Lenticular { phase, .. } | Kind::Cells { phase, .. } => Some(phase),
            Kind::SideBySide => None,
        }
    }

    /// Cone position `t ∈ [0, 1]` seen by colour channel `c` (0 R, 1 G, 2 B) of pixel (x, y).
    pub fn cone_position(&self, x: u32, y: u32, c: usize) -> f64 {
        match &self.kind {
            Kind::Lenticular { layout, phase } => {
                let k = 3 * u64::from(x) + layout.position(c) as u64;
                phase.cone_position(phase.phase(k as f64, f64::from(y)))
            }
            Kind::Cells {
                phase,
                pattern,
                shifts,
            } => {
                let shift = shifts[pattern.cell(x, self.height - 1 - y, shifts.len())][c];
                let k = 3 * u64::from(x);
                phase.cone_position(phase.phase(k as f64, f64::from(y)) + shift)
            }
            // Cone positions at the two view centres, so blending never mixes the eyes.
            Kind::SideBySide if x < self.left_width() => 0.25,
            Kind::SideBySide => 0.75,
        }
    }

    /// Cone positions of every subpixel of row `y`, 3 per pixel in panel order.
    ///
    /// Same values as [`Mapping::cone_position`], without its per-subpixel dispatch.
    pub fn cone_positions_row(&self, y: u32, out: &mut [f64]) {
        match &self.kind {
            Kind::Lenticular { layout, phase } => {
                let row = phase.per_row * f64::from(y);
                let pos = [0, 1, 2].map(|c| layout.position(c) as f64);
                for (x, px) in out.chunks_exact_mut(3).enumerate() {
                    let k0 = 3.0 * x as f64;
                    for (t, p) in px.iter_mut().zip(pos) {
                        // Same operation order as `LensPhase::phase`, so the values agree
                        // bit for bit with `cone_position`.
                        let value = phase.per_subpixel * (k0 + p) + row + phase.offset;
                        *t = phase.cone_position(value);
                    }
                }
            }
            Kind::Cells {
                phase,
                pattern,
                shifts,
            } => {
                let row = phase.per_row * f64::from(y);
                let y_up = self.height - 1 - y;
                for (x, px) in out.chunks_exact_mut(3).enumerate() {
                    let shift = &shifts[pattern.cell(x as u32, y_up, shifts.len())];
                    // Same operation order as `cone_position`, bit for bit.
                    let centre = phase.per_subpixel * (3.0 * x as f64) + row + phase.offset;
                    for (t, s) in px.iter_mut().zip(shift) {
                        *t = phase.cone_position(centre + s);
                    }
                }
            }
            Kind::SideBySide => {
                for (x, px) in out.chunks_exact_mut(3).enumerate() {
                    px.fill(self.cone_position(x as u32, y, 0));
                }
            }
        }
    }

    /// The view shown by channel `c` of pixel (x, y).
    pub fn view_index(&self, x: u32, y: u32, c: usize) -> usize {
        nearest_view(self.cone_position(x, y, c), self.views)
    }

    fn left_width(&self) -> u32 {
        self.width / 2
    }

    /// Column of a `view_w`-wide view image that panel column `x` samples.
    ///
    /// Views are sampled at the panel pixel's normalised position (nearest pixel); on a
    /// side-by-side board each half of the panel covers a whole view.
    pub fn source_x(&self, x: u32, view_w: u32) -> u32 {
        let (pos, span) = match self.kind {
            Kind::SideBySide if x >= self.left_width() => {
                (x - self.left_width(), self.width - self.left_width())
            }
            Kind::SideBySide => (x, self.left_width()),
            Kind::Lenticular { .. } | Kind::Cells { .. } => (x, self.width),
        };
        let sx = scale_index(pos, span, view_w);
        if self.flip_x {
            view_w - 1 - sx
        } else {
            sx
        }
    }

    /// Row of a `view_h`-tall view image that panel row `y` samples.
    pub fn source_y(&self, y: u32, view_h: u32) -> u32 {
        let sy = scale_index(y, self.height, view_h);
        if self.flip_y {
            view_h - 1 - sy
        } else {
            sy
        }
    }
}

/// Index in `0..to` of the cell containing the centre of cell `i` of `0..from`.
fn scale_index(i: u32, from: u32, to: u32) -> u32 {
    let scaled = (2 * u64::from(i) + 1) * u64::from(to) / (2 * u64::from(from));
    (scaled as u32).min(to.saturating_sub(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_index_maps_centres() {
        // Same size: identity.
        assert!((0..7).all(|i| scale_index(i, 7, 7) == i));
        // Halving: pixels 0,1 → 0; 2,3 → 1.
        let halved: Vec<u32> = (0..4).map(|i| scale_index(i, 4, 2)).collect();
        assert_eq!(halved, vec![0, 0, 1, 1]);
        // Doubling: centre of pixel 1 of 2 is at 0.75 → pixel 3 of 4.
        assert_eq!(scale_index(1, 2, 4), 3);
    }

    #[test]
    fn blend_weights_at_centres_and_edges() {
        // Centre of view 2 of 4 is t = 2.5/4.
        assert_eq!(blend_views(2.5 / 4.0, 4), (2, 0.0));
        // Halfway between the centres of views 1 and 2 (t = 2/4): half of each.
        let (i, w) = blend_views(0.5, 4);
        assert_eq!(i, 1);
        assert!((w - 0.5).abs() < 1e-12);
        // Outside the outer centres the outer view is used alone.
        assert_eq!(blend_views(0.01, 4), (0, 0.0));
        assert_eq!(blend_views(0.99, 4), (3, 0.0));
        assert_eq!(blend_views(1.0, 4), (3, 0.0));
    }

    #[test]
    fn nearest_view_clamps_the_top_of_the_cone() {
        assert_eq!(nearest_view(0.0, 48), 0);
        assert_eq!(nearest_view(0.999, 48), 47);
        // t = 1 happens when invView maps frac = 0 to 1 − 0.
        assert_eq!(nearest_view(1.0, 48), 47);
    }
}
