//! Weaving through the lookup table, quilts and side-by-side output.

use image::{Rgb, RgbImage};
use interleave::{
    make_quilt, side_by_side, split_quilt, Blend, Board, ViewFilter, WeaveError, Weaver,
};
use proptest::prelude::*;

/// View `i` is flat grey level `20·i + 5` in every channel.
fn flat_views(n: usize, w: u32, h: u32) -> Vec<RgbImage> {
    (0..n)
        .map(|i| RgbImage::from_pixel(w, h, Rgb([(20 * i + 5) as u8; 3])))
        .collect()
}

/// View `i` encodes its own pixel position: R = x, G = y, B = view index.
fn coordinate_views(n: usize, w: u32, h: u32) -> Vec<RgbImage> {
    (0..n)
        .map(|i| RgbImage::from_fn(w, h, |x, y| Rgb([x as u8, y as u8, i as u8])))
        .collect()
}

fn small_lg_board() -> Board {
    Board::from_toml_str(&small_lg_board_text(), "small.toml").unwrap()
}

fn small_lg_board_text() -> String {
    r#"
        name = "small"
        width = 60
        height = 40
        views = 12
        quilt_cols = 4
        quilt_rows = 3
        view_cone_deg = 40.0
        [looking_glass]
        pitch = 52.0
        slope = -7.0
        center = 0.5
        inv_view = true
        dpi = 30.0
    "#
    .to_string()
}

#[test]
fn nearest_weave_picks_each_subpixel_from_its_view() {
    let board = small_lg_board();
    let m = board.mapping();
    let views = flat_views(12, 60, 40);
    let panel = Weaver::new(&board, 60, 40).weave(&views).unwrap();
    assert_eq!(panel.dimensions(), (60, 40));
    let mut seen = [false; 12];
    for (x, y, px) in panel.enumerate_pixels() {
        for c in 0..3 {
            let v = m.view_index(x, y, c);
            seen[v] = true;
            assert_eq!(px[c], (20 * v + 5) as u8, "({x},{y},{c})");
        }
    }
    assert!(
        seen.iter().all(|&s| s),
        "a 60x40 panel shows every one of 12 views"
    );
}

#[test]
fn small_views_are_sampled_at_the_normalised_position() {
    let board = Board::builtin("generic-8view").unwrap();
    let views = coordinate_views(8, 96, 54);
    let weaver = Weaver::new(&board, 96, 54);
    let panel = weaver.weave(&views).unwrap();
    // Panel pixel (1000, 500) sits at (1000.5/1920, 500.5/1080) = (0.5211, 0.4634) of the
    // view: column floor(0.5211·96) = 50, row floor(0.4634·54) = 25.
    // Its red subpixel shows view (3·1000 + 0 − 500) mod 8 = 4, whose R channel is x = 50.
    assert_eq!(panel.get_pixel(1000, 500)[0], 50);
    // The green subpixel shows view 5; its G channel is the sampled row, 25.
    assert_eq!(panel.get_pixel(1000, 500)[1], 25);
    // Blue: view 6, whose B channel is its own index.
    assert_eq!(panel.get_pixel(1000, 500)[2], 6);
    assert_eq!(weaver.view_at(1000, 500, 2), 6);
    // The last panel pixel samples the last view pixel.
    let last = panel.get_pixel(1919, 1079);
    assert_eq!((last[0], last[1]), (95, 53));
}

#[test]
fn flip_image_flags_mirror_the_sampled_views() {
    let text = small_lg_board_text().replace(
        "dpi = 30.0",
        "dpi = 30.0\nflip_image_x = true\nflip_image_y = true",
    );
    let board = Board::from_toml_str(&text, "flipped.toml").unwrap();
    let views = coordinate_views(12, 60, 40);
    let panel = Weaver::new(&board, 60, 40).weave(&views).unwrap();
    for (x, y, px) in panel.enumerate_pixels() {
        // R carries the sampled view column, G the sampled view row.
        assert_eq!(
            (px[0], px[1]),
            ((59 - x) as u8, (39 - y) as u8),
            "({x},{y})"
        );
    }
}

#[test]
fn side_by_side_board_weaves_as_a_stereo_pair() {
    let board = Board::builtin("sbs-2view").unwrap();
    let (vw, vh) = board.view_size();
    let views: Vec<RgbImage> = (0..2u8)
        .map(|i| RgbImage::from_fn(vw, vh, |x, y| Rgb([(x % 251) as u8, (y % 241) as u8, i])))
        .collect();
    for blend in [Blend::Nearest, Blend::Linear] {
        let panel = Weaver::from_mapping(&board.mapping(), vw, vh, blend, 2)
            .weave(&views)
            .unwrap();
        assert_eq!(panel, side_by_side(&views[0], &views[1]), "{blend:?}");
    }
}

#[test]
fn linear_blend_mixes_the_two_neighbouring_views() {
    let board = small_lg_board();
    let m = board.mapping();
    let views = flat_views(12, 30, 20);
    let panel = Weaver::from_mapping(&board.mapping(), 30, 20, Blend::Linear, 2)
        .weave(&views)
        .unwrap();
    let mut mixed = 0;
    for (x, y, px) in panel.enumerate_pixels() {
        for c in 0..3 {
            // View i is centred at (i + 0.5)/12; the level is linear in the view index,
            // so the blended level is 20·s + 5 with s = 12·t − 0.5 clamped to [0, 11].
            let s = (m.cone_position(x, y, c) * 12.0 - 0.5).clamp(0.0, 11.0);
            let want = 20.0 * s + 5.0;
            assert!(
                (f64::from(px[c]) - want).abs() <= 1.0,
                "({x},{y},{c}): {} vs {want}",
                px[c]
            );
            if s.fract() > 0.2 && s.fract() < 0.8 {
                mixed += 1;
            }
        }
    }
    assert!(
        mixed > 1000,
        "blending should produce in-between levels ({mixed})"
    );
}

#[test]
fn weave_rejects_wrong_views() {
    let board = small_lg_board();
    let weaver = Weaver::new(&board, 30, 20);
    assert_eq!(
        weaver.weave(&flat_views(11, 30, 20)),
        Err(WeaveError::ViewCount {
            expected: 12,
            got: 11
        })
    );
    let mut views = flat_views(12, 30, 20);
    views[7] = RgbImage::new(30, 21);
    let err = weaver.weave(&views).unwrap_err();
    assert_eq!(err.to_string(), "view 7 is 30x21, expected 30x20");
    let empty = Weaver::new(&board, 0, 20);
    assert!(matches!(
        empty.weave(&flat_views(12, 0, 20)),
        Err(WeaveError::EmptyView { .. })
    ));
}

#[test]
fn threads_split_rows_without_changing_the_frame() {
    let board = small_lg_board();
    let views = coordinate_views(12, 30, 20);
    let dimmed = ViewFilter {
        blend: Blend::Gaussian,
        sigma: 0.7,
        dim_edges: 0.2,
    };
    for blend in [
        Blend::Nearest.into(),
        Blend::Linear.into(),
        Blend::Gaussian.into(),
        dimmed,
    ] {
        let one = Weaver::from_mapping(&board.mapping(), 30, 20, blend, 1);
        let frame = one.weave(&views).unwrap();
        for threads in [2, 3, 7, 64] {
            let many = Weaver::from_mapping(&board.mapping(), 30, 20, blend, threads);
            assert_eq!(many.weave(&views).unwrap(), frame, "{blend:?} {threads}");
            let swapped = one.clone().with_threads(threads);
            assert_eq!(swapped.weave(&views).unwrap(), frame, "{blend:?} {threads}");
        }
    }
}

#[test]
fn weave_into_reuses_the_frame() {
    let board = small_lg_board();
    let weaver = Weaver::new(&board, 30, 20);
    let views = coordinate_views(12, 30, 20);
    let mut frame = RgbImage::new(60, 40);
    weaver.weave_into(&views, &mut frame).unwrap();
    assert_eq!(frame, weaver.weave(&views).unwrap());
}

/// generic-8view: `t = frac((3x + c + 0.5 − y)/8)`, so every subpixel sits exactly at
/// the centre of its view `(3x + c − y) mod 8`. Views are flat grey `10·i`.
fn eight_view_pixel(filter: ViewFilter, value: impl Fn(usize) -> u8) -> [u8; 3] {
    let mut board = Board::builtin("generic-8view").unwrap();
    board.set_filter(filter).unwrap();
    let views: Vec<RgbImage> = (0..8)
        .map(|i| RgbImage::from_pixel(4, 4, Rgb([value(i); 3])))
        .collect();
    Weaver::new(&board, 4, 4)
        .weave(&views)
        .unwrap()
        .get_pixel(0, 0)
        .0
}

#[test]
fn gaussian_weave_by_hand() {
    let gaussian = ViewFilter::from(Blend::Gaussian);
    // Pixel (0, 0): R shows view 0, G view 1, B view 2, each at its view's centre.
    // G, σ = 0.5: views 0, 1, 2 at distances 1, 0, 1 weigh e^−2 : 1 : e^−2, i.e.
    // 0.106507, 0.786986, 0.106507 → 27, 201, 27 (/255):
    //   (27·0 + 201·10 + 27·20 + 127) / 255 = 2677 / 255 → 10 (symmetric: the centre's).
    // R: view 0 is the outermost, so its taps are views 0, 1, 2 at distances 0, 1, 2:
    //   1 : e^−2 : e^−8 = 0.880537, 0.119168, 0.000295 → 225, 30, 0:
    //   (225·0 + 30·10 + 0·20 + 127) / 255 = 427 / 255 → 1.
    assert_eq!(eight_view_pixel(gaussian, |i| 10 * i as u8), [1, 10, 20]);
    // Linear and nearest show the centre views unmixed.
    for blend in [Blend::Nearest, Blend::Linear] {
        assert_eq!(
            eight_view_pixel(blend.into(), |i| 10 * i as u8),
            [0, 10, 20]
        );
    }
    // Weights add up to 255: equal views come through unchanged, everywhere.
    let board = small_lg_board();
    let views = vec![flat_views(1, 30, 20).remove(0); 12];
    let panel = Weaver::from_mapping(&board.mapping(), 30, 20, gaussian, 2)
        .weave(&views)
        .unwrap();
    assert!(panel.pixels().all(|p| p.0 == [5; 3]));
}

#[test]
fn edge_dimming_by_hand() {
    let dimmed = ViewFilter {
        dim_edges: 0.25,
        ..ViewFilter::default()
    };
    // Pixel (0, 0) at cone positions t = 0.5/8, 1.5/8, 2.5/8 = 0.0625, 0.1875, 0.3125;
    // brightness smoothstep(t / 0.25): x = 0.25 → 0.25²·(3 − 0.5) = 0.15625 → 40/255;
    // x = 0.75 → 0.75²·(3 − 1.5) = 0.84375 → 215/255; x ≥ 1 → 1.
    // All views grey 200: (200·40 + 127)/255 → 31, (200·215 + 127)/255 → 169, 200.
    assert_eq!(eight_view_pixel(dimmed, |_| 200), [31, 169, 200]);
}

#[test]
fn blend_parses_from_cli_words() {
    assert_eq!("nearest".parse::<Blend>(), Ok(Blend::Nearest));
    assert_eq!("linear".parse::<Blend>(), Ok(Blend::Linear));
    assert_eq!("gaussian".parse::<Blend>(), Ok(Blend::Gaussian));
    assert!("cubic"
        .parse::<Blend>()
        .unwrap_err()
        .to_string()
        .contains("nearest"));
}

#[test]
fn portrait_quilt_has_the_looking_glass_layout() {
    let board = Board::builtin("looking-glass-portrait").unwrap();
    let (cols, rows) = board.quilt_grid();
    let (vw, vh) = (8, 6);
    let quilt = make_quilt(&flat_views(48, vw, vh), cols, rows).unwrap();
    assert_eq!(quilt.dimensions(), (64, 36));
    // View 0 bottom-left, view 7 bottom-right, view 8 starts the next row up, view 47 top-right.
    assert_eq!(quilt.get_pixel(0, 35)[0], 5);
    assert_eq!(quilt.get_pixel(63, 35)[0], 20 * 7 + 5);
    assert_eq!(quilt.get_pixel(0, 29)[0], 20 * 8 + 5);
    assert_eq!(quilt.get_pixel(63, 0)[0], (20 * 47 + 5) as u8);
    assert_eq!(
        interleave::QuiltLayout::of(&board).file_name(),
        "quilt_qs8x6a0.75.png"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn quilt_round_trip(
        cols in 1u32..6, rows in 1u32..6, w in 1u32..9, h in 1u32..9,
        seed in any::<u32>(), spare in 0u32..6,
    ) {
        let n = (cols * rows).saturating_sub(spare.min(cols * rows - 1)) as usize;
        let views: Vec<RgbImage> = (0..n)
            .map(|i| RgbImage::from_fn(w, h, |x, y| {
                let v = seed ^ (i as u32 * 7919 + x * 31 + y * 17);
                Rgb([v as u8, (v >> 8) as u8, (v >> 16) as u8])
            }))
            .collect();
        let quilt = make_quilt(&views, cols, rows).unwrap();
        prop_assert_eq!(quilt.dimensions(), (w * cols, h * rows));
        let back = split_quilt(&quilt, cols, rows, n).unwrap();
        prop_assert_eq!(back, views);
    }
}

/// A random board as TOML: any panel and view sizes, view counts and lens values
/// within (and now and then beyond) the accepted ranges, in each lens form.
fn random_board_text(
    (w, h, views): (u32, u32, u32),
    (vw, vh): (u32, u32),
    lens: u8,
    (a, b, c): (f64, f64, f64),
) -> String {
    let cols = (f64::from(views).sqrt().ceil() as u32).max(1);
    let rows = views.div_ceil(cols);
    let mut text = format!(
        "name = \"random\"\nwidth = {w}\nheight = {h}\nviews = {views}\n\
         quilt_cols = {cols}\nquilt_rows = {rows}\nview_width = {vw}\nview_height = {vh}\n\
         view_cone_deg = 40.0\n"
    );
    match lens {
        0 => text += &format!(
            "[looking_glass]\npitch = {a:e}\nslope = {b:e}\ncenter = {c:e}\ninv_view = true\ndpi = 324.0\n"
        ),
        1 => text += &format!("[van_berkel]\ntan_slant = {b:e}\nlens_pitch = {a:e}\noffset = {c:e}\n"),
        _ => text += "[side_by_side]\n",
    }
    text
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// Any board either is refused with an error or weaves views of any size into a
    /// panel of its own size, with every subpixel taken from an existing view; never a
    /// panic.
    #[test]
    fn any_board_weaves_or_is_refused(
        w in 1u32..48, h in 1u32..48, views in 1u32..300,
        vw in 1u32..24, vh in 1u32..24,
        lens in 0u8..3,
        a_exp in -310.0f64..310.0, b_exp in -310.0f64..310.0, c_exp in -310.0f64..310.0,
        signs in 0u8..8, filter in 0u8..4,
    ) {
        let sign = |bit: u8| if signs & bit != 0 { -1.0 } else { 1.0 };
        let (a, b, c) = (
            sign(1) * 10f64.powf(a_exp / 30.0),
            sign(2) * 10f64.powf(b_exp / 30.0),
            sign(4) * 10f64.powf(c_exp / 30.0),
        );
        let views = if lens == 2 { 2 } else { views };
        let text = random_board_text((w, h, views), (vw, vh), lens, (a, b, c));
        let Ok(board) = Board::from_toml_str(&text, "random.toml") else {
            return Ok(());
        };
        let n = board.views();
        let images = coordinate_views(n, vw, vh);
        let blend = [
            Blend::Nearest.into(),
            Blend::Linear.into(),
            Blend::Gaussian.into(),
            ViewFilter { blend: Blend::Linear, sigma: 0.5, dim_edges: 0.3 },
        ][usize::from(filter)];
        let panel = Weaver::from_mapping(&board.mapping(), vw, vh, blend, 2).weave(&images).unwrap();
        prop_assert_eq!(panel.dimensions(), (w, h));
        for px in panel.pixels() {
            prop_assert!((px[2] as usize) < n.max(1));
        }
        let (cols, rows) = board.quilt_grid();
        let quilt = make_quilt(&images, cols, rows).unwrap();
        prop_assert_eq!(quilt.dimensions(), (vw * cols, vh * rows));
    }
}

/// Issue 26: a quilt or panel whose size comes from a board is allocated fallibly; one
/// that cannot exist is an error, not an overflow panic or an abort.
#[test]
fn an_impossible_quilt_is_an_error() {
    let views = flat_views(1, 1, 1);
    for n in [100_000_000, u32::MAX] {
        let err = make_quilt(&views, n, n).unwrap_err();
        assert!(
            matches!(err, WeaveError::OutOfMemory { what: "quilt", .. }),
            "{err}"
        );
        assert!(err.to_string().contains("cannot be allocated"), "{err}");
    }
}
