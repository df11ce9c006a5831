//! The subpixel → view mapping: hand-computed subpixels, the identities of the
//! Looking-Glass formula, van Berkel ↔ Looking-Glass equivalence and properties.

use interleave::{Board, Mapping};
use proptest::prelude::*;

#[derive(Debug, Clone, Copy)]
struct Lg {
    w: u32,
    h: u32,
    views: u32,
    pitch: f64,
    slope: f64,
    center: f64,
    inv_view: bool,
    dpi: f64,
}

impl Lg {
    fn board(&self, extra: &str) -> Board {
        let text = format!(
            "name = \"t\"\nwidth = {}\nheight = {}\nviews = {}\nquilt_cols = {}\nquilt_rows = 1\n\
             view_cone_deg = 40.0\n{extra}\n[looking_glass]\npitch = {:?}\nslope = {:?}\n\
             center = {:?}\ninv_view = {}\ndpi = {:?}\n",
            self.w,
            self.h,
            self.views,
            self.views,
            self.pitch,
            self.slope,
            self.center,
            self.inv_view,
            self.dpi
        );
        Board::from_toml_str(&text, "test.toml").unwrap()
    }

    /// The Looking-Glass formula exactly as the issue writes it (v = 0 at the bottom row).
    fn reference_t(&self, x: u32, y: u32, c: usize) -> f64 {
        let (w, h) = (f64::from(self.w), f64::from(self.h));
        let u = (f64::from(x) + 0.5) / w;
        let v = (f64::from(self.h - 1 - y) + 0.5) / h;
        let pitch = self.pitch * (w / self.dpi) * (1.0 / self.slope).atan().cos();
        let tilt = h / (w * self.slope);
        let subp = 1.0 / (3.0 * w);
        let phase = (u + c as f64 * subp + v * tilt) * pitch - self.center;
        let f = phase - phase.floor();
        if self.inv_view {
            1.0 - f
        } else {
            f
        }
    }
}

fn van_berkel_board(w: u32, h: u32, views: u32, tan: f64, pitch: f64, offset: f64) -> Board {
    let text = format!(
        "name = \"vb\"\nwidth = {w}\nheight = {h}\nviews = {views}\nquilt_cols = {views}\n\
         quilt_rows = 1\nview_cone_deg = 30.0\n[van_berkel]\ntan_slant = {tan:?}\n\
         lens_pitch = {pitch:?}\noffset = {offset:?}\n"
    );
    Board::from_toml_str(&text, "vb.toml").unwrap()
}

/// Whether `t·n` is so close to a view boundary that rounding may pick either side.
fn near_boundary(t: f64, n: usize) -> bool {
    let s = t * n as f64;
    (s - s.round()).abs() < 1e-7
}

fn portrait() -> Lg {
    Lg {
        w: 1536,
        h: 2048,
        views: 48,
        pitch: 52.0,
        slope: -7.0,
        center: 0.5,
        inv_view: true,
        dpi: 324.0,
    }
}

#[test]
fn small_panel_subpixels_by_hand() {
    // A 10x10 panel, 1 inch wide (DPI 10), slope 4/3 so that cos(atan(3/4)) = 4/5:
    //   pitch' = 5 · (10/10) · 0.8 = 4 lenses across the panel
    //   tilt   = 10 / (10 · 4/3)  = 0.75
    //   subp   = 1/30, so one subpixel step moves the phase by 4/30 = 0.1333…
    let lg = Lg {
        w: 10,
        h: 10,
        views: 10,
        pitch: 5.0,
        slope: 4.0 / 3.0,
        center: 0.1,
        inv_view: true,
        dpi: 10.0,
    };
    let m = lg.board("").mapping();
    // Bottom-left pixel (x 0, image row 9): u = 0.05, v = 0.05.
    //   R: (0.05 + 0.05·0.75)·4 − 0.1 = 0.25    → t = 1 − 0.25    = 0.75    → view 7
    //   G: 0.25 + 0.1333                = 0.3833 → t = 0.6167          → view 6
    //   B: 0.25 + 0.2667                = 0.5167 → t = 0.4833          → view 4
    assert_eq!(
        [
            m.view_index(0, 9, 0),
            m.view_index(0, 9, 1),
            m.view_index(0, 9, 2)
        ],
        [7, 6, 4]
    );
    // Top row, x 3: u = 0.35, v = 0.95.
    //   R: (0.35 + 0.95·0.75)·4 − 0.1 = 4.15 → frac 0.15 → t 0.85 → view 8
    //   B: 4.15 + 0.2667 = 4.4167 → frac 0.4167 → t 0.5833 → view 5
    assert_eq!(m.view_index(3, 0, 0), 8);
    assert_eq!(m.view_index(3, 0, 2), 5);
    // Without invView the same phases give t = frac: 0.25 → view 2.
    let plain = Lg {
        inv_view: false,
        ..lg
    };
    assert_eq!(plain.board("").mapping().view_index(0, 9, 0), 2);
}

#[test]
fn portrait_bottom_left_pixel_by_hand() {
    // pitch' = 52 · (1536/324) · cos(atan(−1/7)) = 52 · 4.740741 · 0.989949 = 244.0409
    // tilt   = 2048 / (1536 · −7) = −0.190476;  subp·pitch' = 244.0409 / 4608 = 0.052960
    // Pixel (0, 2047) is the bottom row: u = 0.5/1536 = 0.000326, v = 0.5/2048 = 0.000244
    //   R: (0.000326 − 0.000244·0.190476)·244.0409 − 0.5 = 0.068092 − 0.5 = −0.431908
    //      frac = 0.568092, t = 0.431908, t·48 = 20.73 → view 20
    //   G: −0.431908 + 0.052960 = −0.378948 → t = 0.378948 → 18.19 → view 18
    //   B: −0.378948 + 0.052960 = −0.325988 → t = 0.325988 → 15.65 → view 15
    let m = portrait().board("").mapping();
    let got: Vec<usize> = (0..3).map(|c| m.view_index(0, 2047, c)).collect();
    assert_eq!(got, vec![20, 18, 15]);
    assert!((m.cone_position(0, 2047, 0) - 0.431908).abs() < 1e-6);
}

#[test]
fn builtin_portrait_matches_the_formula_everywhere_sampled() {
    let lg = portrait();
    let m = Board::builtin("looking-glass-portrait").unwrap().mapping();
    let mut checked = 0;
    for y in (0..lg.h).step_by(37) {
        for x in (0..lg.w).step_by(13) {
            for c in 0..3 {
                let t = lg.reference_t(x, y, c);
                assert!((m.cone_position(x, y, c) - t).abs() < 1e-9, "({x},{y},{c})");
                if !near_boundary(t, 48) {
                    let want = ((t * 48.0).floor() as usize).min(47);
                    assert_eq!(m.view_index(x, y, c), want, "({x},{y},{c})");
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 10_000);
}

#[test]
fn row_evaluation_agrees_bit_for_bit_with_single_subpixels() {
    for name in ["looking-glass-go", "generic-8view", "sbs-2view"] {
        let board = Board::builtin(name).unwrap();
        let m = board.mapping();
        let (w, h) = board.panel_size();
        let mut row = vec![0.0; 3 * w as usize];
        for y in [0, 1, h / 2, h - 1] {
            m.cone_positions_row(y, &mut row);
            for x in 0..w {
                for c in 0..3 {
                    assert_eq!(row[3 * x as usize + c], m.cone_position(x, y, c), "{name}");
                }
            }
        }
    }
}

/// Cone position difference on the circle (t and t ± 1 are the same phase).
fn circular_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(1.0);
    d.min(1.0 - d)
}

#[test]
fn identities_of_the_looking_glass_form() {
    let lg = Lg {
        inv_view: false,
        ..portrait()
    };
    let m = lg.board("").mapping();
    let w = f64::from(lg.w);
    let pitch = 52.0 * (w / 324.0) * (-1.0f64 / 7.0).atan().cos();
    // Next subpixel: the phase advances by subp·pitch' = pitch'/(3W).
    let step_c = pitch / (3.0 * w);
    // One row up: the phase advances by tilt·pitch'/H = pitch'/(W·slope).
    let step_up = pitch / (w * -7.0);
    for &(x, y) in &[(0, 1), (100, 700), (1534, 2047)] {
        let t0 = m.cone_position(x, y, 0);
        assert!(circular_diff(m.cone_position(x, y, 1), t0 + step_c) < 1e-9);
        assert!(circular_diff(m.cone_position(x, y, 2), t0 + 2.0 * step_c) < 1e-9);
        assert!(circular_diff(m.cone_position(x + 1, y, 0), t0 + 3.0 * step_c) < 1e-9);
        assert!(circular_diff(m.cone_position(x, y - 1, 0), t0 + step_up) < 1e-9);
    }
    // Shifting `center` by a whole lens changes nothing.
    let shifted = Lg {
        center: 0.5 + 3.0,
        inv_view: false,
        ..portrait()
    }
    .board("")
    .mapping();
    for &(x, y, c) in &[(0, 0, 0), (77, 1000, 1), (1535, 2047, 2)] {
        assert!(circular_diff(shifted.cone_position(x, y, c), m.cone_position(x, y, c)) < 1e-9);
    }
}

#[test]
fn inv_view_reverses_the_view_order() {
    let plain = Lg {
        inv_view: false,
        ..portrait()
    }
    .board("")
    .mapping();
    let inv = portrait().board("").mapping();
    let mut compared = 0;
    for y in (0..2048).step_by(101) {
        for x in (0..1536).step_by(7) {
            for c in 0..3 {
                if near_boundary(plain.cone_position(x, y, c), 48) {
                    continue;
                }
                // floor((1 − f)·N) = N − 1 − floor(f·N) away from boundaries.
                assert_eq!(
                    inv.view_index(x, y, c),
                    47 - plain.view_index(x, y, c),
                    "({x},{y},{c})"
                );
                compared += 1;
            }
        }
    }
    assert!(compared > 10_000);
}

#[test]
fn flips_negate_tilt_and_swap_red_and_blue() {
    let base = portrait();
    let m = base.board("").mapping();
    let flip_x = base.board("").mapping_with(|lg| lg.flip_image_x = true);
    // flip_image_x negates tilt: going one row up moves the phase the other way.
    let up = |m: &Mapping| {
        let a = m.lens_phase().unwrap();
        -a.per_row
    };
    assert!((up(&flip_x) + up(&m)).abs() < 1e-12);
    assert!(up(&m).abs() > 1e-3);
    // flip_subp puts red where blue was; a BGR panel is the same thing.
    let flip_subp = base.board("").mapping_with(|lg| lg.flip_subp = true);
    let bgr = base.board("subpixels = \"bgr\"").mapping();
    for &(x, y) in &[(0, 0), (321, 654), (1535, 2047)] {
        assert_eq!(flip_subp.view_index(x, y, 0), m.view_index(x, y, 2));
        assert_eq!(flip_subp.view_index(x, y, 2), m.view_index(x, y, 0));
        assert_eq!(flip_subp.view_index(x, y, 1), m.view_index(x, y, 1));
        assert_eq!(bgr.view_index(x, y, 0), m.view_index(x, y, 2));
    }
}

/// Lets a test tweak a board's Looking-Glass values through a calibration round trip.
trait MappingWith {
    fn mapping_with(self, f: impl FnOnce(&mut interleave::LookingGlass)) -> Mapping;
}

impl MappingWith for Board {
    fn mapping_with(self, f: impl FnOnce(&mut interleave::LookingGlass)) -> Mapping {
        let interleave::Lens::LookingGlass(mut lg) = self.lens().clone() else {
            panic!("not a Looking-Glass board");
        };
        f(&mut lg);
        let json = format!(
            r#"{{"pitch": {{"value": {}}}, "slope": {{"value": {}}}, "center": {{"value": {}}},
                "invView": {{"value": {}}}, "DPI": {{"value": {}}},
                "flipImageX": {{"value": {}}}, "flipImageY": {{"value": {}}},
                "flipSubp": {{"value": {}}}}}"#,
            lg.pitch,
            lg.slope,
            lg.center,
            u8::from(lg.inv_view),
            lg.dpi,
            u8::from(lg.flip_image_x),
            u8::from(lg.flip_image_y),
            u8::from(lg.flip_subp)
        );
        let cal = interleave::Calibration::from_json_str(&json, "tweak.json").unwrap();
        let mut board = self;
        board.apply_calibration(&cal).unwrap();
        board.mapping()
    }
}

#[test]
fn generic_8view_is_3x_plus_c_minus_y_mod_8() {
    let m = Board::builtin("generic-8view").unwrap().mapping();
    for y in 0..40 {
        for x in 0..40 {
            for c in 0..3 {
                let want = (3 * x as i64 + c as i64 - y as i64).rem_euclid(8) as usize;
                assert_eq!(m.view_index(x, y, c), want, "({x},{y},{c})");
            }
        }
    }
    let m4 = Board::builtin("generic-4view").unwrap().mapping();
    // slant_deg = atan(1/3) in degrees gives the same pattern with period 4.
    assert_eq!(m4.view_index(5, 3, 1), (15 + 1 - 3) % 4);
}

#[test]
fn van_berkel_equals_looking_glass_with_converted_parameters() {
    // Looking Glass: phase = (k + 1.5)·pitch'/(3W) + (y_up + 0.5)·pitch'/(W·slope) − center.
    // Van Berkel:    phase = (k + offset − 3·y·tanα) / X, y counted from the top.
    // Matching the k terms: X = 3W/pitch'. Matching the y terms with y_up = H − 1 − y:
    // −3·tanα/X = −pitch'/(W·slope), i.e. tanα = 1/slope. The constants then give
    // offset = X·(1.5·pitch'/(3W) + (H − 0.5)·pitch'/(W·slope) − center).
    for (slope, center) in [(-7.0, 0.5), (5.5, -0.3), (-6.3, 2.25)] {
        let lg = Lg {
            w: 96,
            h: 64,
            views: 45,
            pitch: 40.0,
            slope,
            center,
            inv_view: false,
            dpi: 120.0,
        };
        let (w, h) = (96.0, 64.0);
        let pitch = lg.pitch * (w / lg.dpi) * (1.0f64 / slope).atan().cos();
        let x_sub = 3.0 * w / pitch;
        let offset = x_sub * (1.5 * pitch / (3.0 * w) + (h - 0.5) * pitch / (w * slope) - center);
        let vb = van_berkel_board(96, 64, 45, 1.0 / slope, x_sub, offset).mapping();
        let lgm = lg.board("").mapping();
        for y in 0..64 {
            for x in 0..96 {
                for c in 0..3 {
                    let (a, b) = (lgm.cone_position(x, y, c), vb.cone_position(x, y, c));
                    assert!(circular_diff(a, b) < 1e-9, "({x},{y},{c}): {a} vs {b}");
                    if !near_boundary(a, 45) {
                        assert_eq!(lgm.view_index(x, y, c), vb.view_index(x, y, c));
                    }
                }
            }
        }
    }
}

fn lg_strategy() -> impl Strategy<Value = Lg> {
    (
        1u32..48,
        1u32..48,
        2u32..=256,
        5.0f64..120.0,
        prop_oneof![-12.0f64..-1.5, 1.5f64..12.0],
        -3.0f64..3.0,
        any::<bool>(),
        80.0f64..600.0,
    )
        .prop_map(|(w, h, views, pitch, slope, center, inv_view, dpi)| Lg {
            w,
            h,
            views,
            pitch,
            slope,
            center,
            inv_view,
            dpi,
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn every_view_index_is_in_range(lg in lg_strategy()) {
        let board = lg.board("");
        let weaver = interleave::Weaver::from_mapping(&board.mapping(), 3, 2, interleave::Blend::Linear, 2);
        let m = board.mapping();
        for y in 0..lg.h {
            for x in 0..lg.w {
                for c in 0..3 {
                    let t = m.cone_position(x, y, c);
                    prop_assert!((0.0..=1.0).contains(&t));
                    prop_assert!(m.view_index(x, y, c) < lg.views as usize);
                    prop_assert!(weaver.view_at(x, y, c) < lg.views as usize);
                }
            }
        }
    }

    #[test]
    fn looking_glass_phase_is_periodic_in_the_lens_pitch(
        lg in lg_strategy(), k in 0.0f64..5000.0, y in 0.0f64..4000.0, lenses in 1i32..5,
    ) {
        let m = lg.board("").mapping();
        let phase = m.lens_phase().unwrap();
        let x_sub = phase.lens_pitch_subpixels();
        let here = phase.cone_position(phase.phase(k, y));
        let there = phase.cone_position(phase.phase(k + f64::from(lenses) * x_sub, y));
        prop_assert!(circular_diff(here, there) < 1e-9);
    }

    #[test]
    fn van_berkel_views_repeat_every_lens(
        pixels_per_lens in 1u32..6, views in 2u32..24, tan in -0.6f64..0.6,
        offset in 0.0f64..10.0, x in 0u32..40, y in 0u32..40, c in 0usize..3,
    ) {
        // A lens of a whole number of pixels: shifting by it lands on the same channel.
        let board = van_berkel_board(80, 40, views, tan, f64::from(3 * pixels_per_lens), offset);
        let m = board.mapping();
        let t = m.cone_position(x, y, c);
        let t_next = m.cone_position(x + pixels_per_lens, y, c);
        prop_assert!(circular_diff(t, t_next) < 1e-9);
        if !near_boundary(t, views as usize) {
            prop_assert_eq!(m.view_index(x, y, c), m.view_index(x + pixels_per_lens, y, c));
        }
    }
}
