//! Properties of the LDI renderer that hold for any scene.

use crate::ldi_support;

use ldi_support::*;
use reshader::depth::DepthMap;
use reshader::io::photo::SrgbImage;
use reshader::relocate::ldi::{BandColours, Border, Ldi, LdiConfig, LdiRelocator, Silhouettes};
use reshader::relocate::reach_of;
use reshader::relocate::{RelocateError, Relocator};

/// A small deterministic generator for random scenes.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: usize, hi: usize) -> usize {
        lo + (self.next() * (hi - lo) as f64) as usize
    }
}

/// Red boxes at random depths, apart from each other, in front of a tilted wall.
fn random_scene(seed: u64) -> Scene {
    let mut rng = Lcg(seed);
    let mut scene = Scene::wall(4.0);
    let tilt = 1.0 + rng.next() as f32 * 2.0;
    for y in 0..H {
        for x in 0..W {
            scene.depth[y * W + x] = 3.0 + tilt * x as f32 / W as f32;
        }
    }
    let mut taken = vec![false; W * H];
    for _ in 0..rng.range(1, 6) {
        let (x0, y0) = (rng.range(0, W - 4), rng.range(0, H - 4));
        let (x1, y1) = (
            rng.range(x0 + 1, W.min(x0 + 20)),
            rng.range(y0 + 1, H.min(y0 + 20)),
        );
        // Boxes keep a pixel of wall between them: each box's band extends the wall.
        let grown = |x: usize, y: usize| taken[y * W + x];
        let clash = (y0.saturating_sub(1)..(y1 + 1).min(H))
            .any(|y| (x0.saturating_sub(1)..(x1 + 1).min(W)).any(|x| grown(x, y)));
        if clash {
            continue;
        }
        for y in y0..y1 {
            for x in x0..x1 {
                taken[y * W + x] = true;
            }
        }
        let depth = 0.8 + 1.5 * rng.next() as f32;
        scene = scene.rect(x0..x1, y0..y1, RED, depth);
    }
    scene
}

#[test]
fn a_plane_at_the_focus_depth_is_unchanged_in_every_view() {
    let mut colours = SrgbImage::new(W as u32, H as u32);
    for y in 0..H {
        for x in 0..W {
            let v = ((x * 7 + y * 13) % 11) as f32 / 10.0;
            colours.put(
                x as u32,
                y as u32,
                [v, x as f32 / W as f32, y as f32 / H as f32],
            );
        }
    }
    let focus = 2.5;
    let depth = DepthMap::new(W, H, vec![focus as f32; W * H]);
    let ldi = Ldi::build(&colours, &depth, &camera(), &LdiConfig::default(), 0.3).unwrap();
    for tx in [-0.3, -0.11, 0.0, 0.07, 0.3] {
        let out = ldi.render(&colours, &view(tx, focus)).unwrap();
        for (a, b) in out.data().iter().zip(colours.data()) {
            assert!((a - b).abs() < 1e-5, "tx={tx}: {a} vs {b}");
        }
    }
}

#[test]
fn no_pixel_of_any_view_is_a_hole() {
    for seed in 0..12 {
        let scene = random_scene(seed);
        for border in [Border::Extend, Border::Crop] {
            let config = LdiConfig {
                border,
                ..LdiConfig::default()
            };
            let ldi = scene.build(&config, 0.25);
            for tx in [-0.25, -0.1, 0.1, 0.25] {
                let view = render(&ldi, &scene, tx, 3.5);
                let holes = view.hole_fraction.iter().filter(|&&h| h > 0.0).count();
                assert_eq!(
                    holes, 0,
                    "seed {seed} {border:?} tx={tx}: {holes} pixels not covered"
                );
            }
        }
    }
}

#[test]
fn crop_framing_fitted_to_the_views_is_just_enough() {
    let config = LdiConfig {
        border: Border::Crop,
        ..LdiConfig::default()
    };
    let holes = |ldi: &Ldi, scene: &Scene, tx: f64| {
        let view = render(ldi, scene, tx, 3.5);
        view.hole_fraction.iter().filter(|&&h| h > 0.0).count()
    };
    for seed in 0..6 {
        let scene = random_scene(seed);
        let mut ldi = scene.build(&config, 0.25);
        let any_focus = ldi.stats().crop;
        let served = [-0.2, -0.1, 0.1, 0.2].map(|tx| view(tx, 3.5));
        ldi.fit_frame(&served);
        let fitted = ldi.stats().crop;
        // The focus plane lies amid the scene's depths: each side needs less.
        assert!(
            1.0 < fitted && fitted < any_focus,
            "seed {seed}: {fitted} against {any_focus}"
        );
        for tx in [-0.2, -0.15, 0.0, 0.1, 0.2] {
            assert_eq!(holes(&ldi, &scene, tx), 0, "seed {seed} tx={tx}");
        }
        // Just enough: a view beyond those served sees past the photo's edge.
        let beyond = holes(&ldi, &scene, -0.4) + holes(&ldi, &scene, 0.4);
        assert!(beyond > 0, "seed {seed}: a view at 0.4 saw no border");
    }
}

#[test]
fn foreground_colours_never_appear_in_a_disoccluded_band() {
    let mut checked = 0;
    for seed in 100..116 {
        let scene = random_scene(seed);
        let ldi = scene.build(&LdiConfig::default(), 0.25);
        for tx in [-0.25, 0.25] {
            let view = render(&ldi, &scene, tx, 3.5);
            for (i, &front) in view.front_fraction.iter().enumerate() {
                if front == 0.0 {
                    checked += 1;
                    let red = view.image.data()[3 * i];
                    assert_eq!(
                        red,
                        0.0,
                        "seed {seed} tx={tx}: red at ({}, {})",
                        i % W,
                        i / W
                    );
                }
            }
        }
    }
    assert!(
        checked > 500,
        "the scenes must uncover something: {checked} pixels"
    );
}

#[test]
fn the_band_is_inpainted_from_the_wall_texture() {
    let scene = Scene::wall(4.0).rect(20..40, 10..38, RED, 1.0);
    let ldi = scene.build(&LdiConfig::default(), 0.2);
    let view = render(&ldi, &scene, 0.2, 4.0);
    // Wall pixels are [0, 0.1 or 0.4, 0.8]; subsample averages stay between the two.
    let mut band_pixels = 0;
    for (i, &front) in view.front_fraction.iter().enumerate() {
        if front == 0.0 {
            band_pixels += 1;
            let [r, g, b] = view.image.get((i % W) as u32, (i / W) as u32);
            let is_wall =
                r == 0.0 && (b - 0.8).abs() < 1e-6 && (0.1 - 1e-6..=0.4 + 1e-6).contains(&g);
            assert!(
                is_wall,
                "({}, {}): {:?} is not wall",
                i % W,
                i / W,
                [r, g, b]
            );
        }
    }
    assert!(band_pixels > 100, "{band_pixels}");
}

#[test]
fn the_band_continues_the_wall_stripes_instead_of_repeating_one_pixel_per_row() {
    let scene = Scene::wall(4.0).rect(20..40, 10..38, RED, 1.0);
    // The synthesis itself: smoothing averages 3-px stripes away on purpose.
    let config = LdiConfig {
        band_smoothing: 0,
        ..LdiConfig::default()
    };
    let ldi = scene.build(&config, 0.2);
    let view = render(&ldi, &scene, 0.2, 4.0);
    // The wall's stripes are 3 px wide, so a row of 6 or more band pixels that continues
    // them shows both stripe colours; a row copied from one pixel shows one.
    let (mut rows, mut striped) = (0, 0);
    for y in 0..H {
        let greens: Vec<f32> = (0..W)
            .filter(|&x| view.front_fraction[y * W + x] == 0.0)
            .map(|x| view.image.get(x as u32, y as u32)[1])
            .collect();
        if greens.len() >= 6 {
            rows += 1;
            let (lo, hi) = greens.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &g| {
                (lo.min(g), hi.max(g))
            });
            striped += usize::from(hi - lo > 0.2);
        }
    }
    assert!(rows >= 20, "the view must uncover a wide band: {rows} rows");
    assert!(
        striped * 10 >= rows * 8,
        "{striped} of {rows} band rows striped"
    );
}

#[test]
fn the_reported_memory_counts_the_band_colours() {
    let scene = Scene::wall(4.0).rect(20..40, 10..38, RED, 1.0);
    let with = |band_smoothing, band_colours| {
        let config = LdiConfig {
            band_smoothing,
            band_colours,
            ..LdiConfig::default()
        };
        scene.build(&config, 0.2).stats()
    };
    let bare = with(0, BandColours::View);
    assert!(bare.band_samples > 100, "{}", bare.band_samples);
    // One RGB triple per band sample: the smoothing's offsets, or the build-time colours.
    let per_sample = bare.band_samples * std::mem::size_of::<[f32; 3]>();
    for (smoothing, colours) in [(3, BandColours::View), (0, BandColours::Inpainted)] {
        let stats = with(smoothing, colours);
        assert_eq!(
            stats.memory_bytes,
            bare.memory_bytes + per_sample,
            "smoothing {smoothing}, {colours:?}"
        );
    }
}

#[test]
fn each_view_takes_the_front_colours_from_its_own_image() {
    let scene = Scene::wall(4.0).rect(20..40, 10..38, RED, 1.0);
    let ldi = scene.build(&LdiConfig::default(), 0.2);
    // A "reshaded" image: everything darker.
    let mut dim = scene.colours.clone();
    for y in 0..H as u32 {
        for x in 0..W as u32 {
            dim.put(x, y, scene.colours.get(x, y).map(|c| c * 0.5));
        }
    }
    let bright = ldi
        .render_detailed(&scene.colours, &view(0.1, 4.0))
        .unwrap();
    let dark = ldi.render(&dim, &view(0.1, 4.0)).unwrap();
    let band = bright.front_fraction.iter().filter(|&&f| f == 0.0).count();
    assert!(band > 100, "the view uncovers {band} band pixels");
    for ((b, d), &front) in bright
        .image
        .data()
        .chunks_exact(3)
        .zip(dark.data().chunks_exact(3))
        .zip(&bright.front_fraction)
    {
        for (b, d) in b.iter().zip(d) {
            if front == 1.0 {
                assert!((d - 0.5 * b).abs() < 1e-6);
            } else {
                // The band copies the dimmed wall; its smoothing is the build image's.
                assert!(
                    d < b || *b == 0.0,
                    "band {d} in the dim view, {b} in the bright"
                );
            }
        }
    }
}

/// A red box in front of a wall that is blue up to column 44 and green from there; the
/// box's right edge (column 39) is half red, half the blue beside it, as a photo's edge
/// pixels are. The wall is the zero-parallax plane.
fn box_with_a_mixed_edge() -> Scene {
    const BLUE: [f32; 3] = [0.0, 0.0, 0.8];
    let mut scene = Scene::wall(2.0);
    for y in 0..H {
        for x in 0..W {
            let c = if x < 44 { BLUE } else { GREEN };
            scene.colours.put(x as u32, y as u32, c);
        }
    }
    let mut scene = scene.rect(16..40, 8..40, RED, 1.0);
    for y in 8..40 {
        scene.colours.put(39, y, [0.5, 0.0, 0.4]);
    }
    scene
}

/// `scene` seen from a camera at `tx` (focus on the wall) with hard and with soft
/// silhouettes, once the soft LDI is checked to give the photo back at its own camera;
/// with the soft LDI's count of soft pixels.
fn hard_and_soft(scene: &Scene, tx: f64) -> (SrgbImage, SrgbImage, usize) {
    let build = |silhouettes| {
        let config = LdiConfig {
            silhouettes,
            ..LdiConfig::default()
        };
        scene.build(&config, 0.3)
    };
    let soft = build(Silhouettes::Soft);
    let at_input = soft.render(&scene.colours, &view(0.0, 2.0)).unwrap();
    for (got, want) in at_input.data().iter().zip(scene.colours.data()) {
        assert!(
            (got - want).abs() < 1e-5,
            "{got} vs {want} at the photo's camera"
        );
    }
    let moved = view(tx, 2.0);
    let hard = build(Silhouettes::Hard);
    (
        hard.render(&scene.colours, &moved).unwrap(),
        soft.render(&scene.colours, &moved).unwrap(),
        soft.stats().soft_pixels,
    )
}

#[test]
fn soft_silhouettes_keep_the_photo_and_leave_no_rim_of_its_background() {
    // The box moves about 8 px right over the wall, and its right edge lands on green.
    assert!((shift(-0.3, 1.0, 2.0) - 8.0).abs() < 1.0);
    let (hard, soft, soft_pixels) = hard_and_soft(&box_with_a_mixed_edge(), -0.3);
    assert_eq!(soft_pixels, 32, "one soft pixel per row of the edge");
    let rim = |image: &SrgbImage| {
        (8..40)
            .flat_map(|y| (44..W).map(move |x| image.get(x as u32, y as u32)))
            .map(|c| if c[0] > 0.2 { c[2] } else { 0.0 })
            .fold(0.0f32, f32::max)
    };
    let (hard_rim, soft_rim) = (rim(&hard), rim(&soft));
    assert!(
        hard_rim > 0.15,
        "hard: the blue comes along over the green ({hard_rim})"
    );
    assert!(
        soft_rim < 0.05,
        "soft: the green behind it shows ({soft_rim})"
    );
}

#[test]
fn soft_silhouettes_take_the_foreground_share_of_the_background_along() {
    // The box's edge spread the other way: the wall pixel beside it (column 40) is half
    // red, as a photo's edge pixels are when depth puts them in the background.
    let mut scene = box_with_a_mixed_edge();
    for y in 8..40 {
        scene.colours.put(39, y, RED);
        scene.colours.put(40, y, [0.5, 0.0, 0.4]);
    }
    // Rows 9-38 (the box's corner rows have a second cut); the box moves about 8 px
    // left, and the wall at column 40 is in plain view.
    let (hard, soft, soft_pixels) = hard_and_soft(&scene, 0.3);
    assert!(soft_pixels >= 30, "{soft_pixels} soft pixels");
    let ghost = |image: &SrgbImage| (10..38).map(|y| image.get(40, y)[0]).fold(0.0f32, f32::max);
    let (hard_ghost, soft_ghost) = (ghost(&hard), ghost(&soft));
    assert!(
        hard_ghost > 0.4,
        "hard: the red share stays on the wall ({hard_ghost})"
    );
    assert!(
        soft_ghost < 0.05,
        "soft: it went with the box ({soft_ghost})"
    );
}

#[test]
fn the_relocator_prepares_once_and_renders_every_view_from_it() {
    let scene = random_scene(7);
    let depth = scene.depth_map();
    let relocator = LdiRelocator::default();
    let views = [view(-0.3, 3.5), view(0.1, 3.5), view(0.3, 3.5)];
    let reach = reach_of(views.iter().map(|v| v.centre), &camera());
    assert!((reach - 0.3).abs() < 1e-12);
    let prepared = relocator
        .prepare(&scene.colours, &depth, &camera(), &views)
        .unwrap();
    let ldi = scene.build(&LdiConfig::default(), reach);
    for v in &views {
        let image = prepared.render(&scene.colours, v).unwrap();
        assert_eq!(image, ldi.render(&scene.colours, v).unwrap());
    }
    // One view on its own prepares for exactly that view.
    let alone = relocator
        .render(&scene.colours, &depth, &camera(), &views[0])
        .unwrap();
    assert_eq!(alone, ldi.render(&scene.colours, &views[0]).unwrap());
    assert!(relocator.description().contains("layered depth image"));
}

#[test]
fn inpainted_band_colours_do_not_follow_the_view_image() {
    let scene = Scene::wall(4.0).rect(20..40, 10..38, RED, 1.0);
    let config = LdiConfig {
        band_colours: BandColours::Inpainted,
        ..LdiConfig::default()
    };
    let ldi = scene.build(&config, 0.2);
    let mut dim = scene.colours.clone();
    for y in 0..H as u32 {
        for x in 0..W as u32 {
            dim.put(x, y, scene.colours.get(x, y).map(|c| c * 0.5));
        }
    }
    let v = view(0.2, 4.0);
    let bright = ldi.render_detailed(&scene.colours, &v).unwrap();
    let dark = ldi.render(&dim, &v).unwrap();
    let (mut band, mut front) = (0, 0);
    for (i, &f) in bright.front_fraction.iter().enumerate() {
        let (b, d) = (
            &bright.image.data()[3 * i..3 * i + 3],
            &dark.data()[3 * i..3 * i + 3],
        );
        if f == 0.0 {
            band += 1;
            assert_eq!(b, d, "band pixel {i} changed with the view's colours");
        } else if f == 1.0 {
            front += 1;
            assert!(b.iter().zip(d).all(|(b, d)| (d - 0.5 * b).abs() < 1e-6));
        }
    }
    assert!(band > 100 && front > 1000, "{band} {front}");
}

#[test]
fn mismatched_sizes_are_an_error() {
    let scene = random_scene(1);
    let small = SrgbImage::new(W as u32 - 1, H as u32);
    let err = LdiRelocator::default()
        .render(&small, &scene.depth_map(), &camera(), &view(0.1, 3.5))
        .unwrap_err();
    assert!(matches!(err, RelocateError::SizeMismatch { .. }));
    let ldi = scene.build(&LdiConfig::default(), 0.1);
    assert!(ldi.render(&small, &view(0.1, 3.5)).is_err());
}

/// A random camera offset along one axis: zero, ordinary, or absurdly large or small
/// (1e-30 to 1e30 scene units), either sign.
fn random_offset(rng: &mut Lcg) -> f64 {
    match rng.range(0, 4) {
        0 => 0.0,
        1 => (rng.next() - 0.5) * 0.6,
        _ => {
            let magnitude = 10f64.powf(rng.next() * 60.0 - 30.0);
            if rng.next() < 0.5 {
                -magnitude
            } else {
                magnitude
            }
        }
    }
}

/// The renderer is total: any camera, any depth scale gives an image of the view's
/// size with colours in [0, 1], never a panic. (The "no sample" marker used to reach the
/// colour lookup as an index when a view saw nothing, and the band width overflowed
/// for far cameras.) Seeded, so a failure reproduces.
#[test]
fn any_camera_and_any_depth_scale_render_an_image() {
    let mut rng = Lcg(0x5eed_2026);
    let mut saw_nothing = 0;
    for case in 0..160 {
        let scene = random_scene(case);
        let scale = 10f32.powf(rng.next() as f32 * 60.0 - 30.0);
        let depth = DepthMap::new(W, H, scene.depth.iter().map(|d| d * scale).collect());
        let focus = 3.5 * f64::from(scale);
        let centre = [
            random_offset(&mut rng),
            random_offset(&mut rng),
            random_offset(&mut rng),
        ]
        .map(|c| c * f64::from(scale));
        let border = if case % 2 == 0 {
            Border::Extend
        } else {
            Border::Crop
        };
        let config = LdiConfig {
            border,
            band_colours: if case % 3 == 0 {
                BandColours::Inpainted
            } else {
                BandColours::View
            },
            ..LdiConfig::default()
        };
        // The CLI refuses cameras beyond the focus plane or absurdly far away
        // (`ViewCamera::off_axis`); the renderer takes them anyway, unsheared.
        let view = reshader::views::ViewCamera::off_axis(&camera(), centre, focus).unwrap_or(
            reshader::views::ViewCamera {
                centre,
                intrinsics: camera(),
            },
        );
        let what = format!("case {case}: depth x{scale:e}, camera {centre:?}");
        let reach = reach_of([centre], &camera());
        let ldi = Ldi::build(&scene.colours, &depth, &camera(), &config, reach)
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        let out = ldi
            .render_detailed(&scene.colours, &view)
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(
            (out.image.width(), out.image.height()),
            (W as u32, H as u32)
        );
        assert!(
            out.image.data().iter().all(|v| (0.0..=1.0).contains(v)),
            "{what}: colours out of range"
        );
        if out.hole_fraction.iter().all(|&h| h == 1.0) {
            saw_nothing += 1;
        }
        // The mesh warp is total too.
        let mesh = reshader::relocate::MeshWarp::default()
            .render(&scene.colours, &depth, &camera(), &view)
            .unwrap_or_else(|e| panic!("{what} (mesh): {e}"));
        assert_eq!((mesh.width(), mesh.height()), (W as u32, H as u32));
    }
    assert!(saw_nothing > 0, "no case had a view that sees nothing");
}

/// Depth in other units (a power of two apart, so every value scales exactly) with the
/// cameras in the same units is the same picture, bit for bit: the LDI computes in its
/// own units, so no threshold depends on the depth map's.
#[test]
fn a_scene_in_other_units_renders_the_same() {
    let scene = random_scene(3);
    let reference = {
        let ldi = scene.build(&LdiConfig::default(), 0.25);
        ldi.render(&scene.colours, &view(0.25, 3.5)).unwrap()
    };
    for exponent in [-100, -20, -1, 1, 20, 100] {
        let s = 2f64.powi(exponent);
        let depth = DepthMap::new(W, H, scene.depth.iter().map(|d| d * s as f32).collect());
        let ldi = Ldi::build(
            &scene.colours,
            &depth,
            &camera(),
            &LdiConfig::default(),
            0.25 * s,
        )
        .unwrap();
        let v = reshader::views::ViewCamera::off_axis(&camera(), [0.25 * s, 0.0, 0.0], 3.5 * s)
            .unwrap();
        assert_eq!(
            ldi.render(&scene.colours, &v).unwrap(),
            reference,
            "depth x2^{exponent}"
        );
    }
}

/// The mesh warp, like the LDI, computes in its own units: a random scene at any depth
/// scale from 2^-100 (about 1e-30) to 2^100, with its camera in the same units, renders
/// the picture it renders at scale 1, bit for bit, and that picture is not black. (At
/// depth 1e-30 every view was black: the parallax underflowed in view pixels.)
#[test]
fn the_mesh_warp_renders_a_scene_in_any_units_the_same() {
    let mut rng = Lcg(0x3e54_2026);
    for case in 0..24 {
        let scene = random_scene(100 + case);
        let offset =
            [random_offset(&mut rng), random_offset(&mut rng), 0.0].map(|c| c.clamp(-0.5, 0.5));
        let render = |s: f64| {
            let depth = DepthMap::new(W, H, scene.depth.iter().map(|d| d * s as f32).collect());
            let view =
                reshader::views::ViewCamera::off_axis(&camera(), offset.map(|c| c * s), 3.5 * s)
                    .unwrap();
            reshader::relocate::MeshWarp::default()
                .render(&scene.colours, &depth, &camera(), &view)
                .unwrap_or_else(|e| panic!("case {case}, depth x{s:e}: {e}"))
        };
        let reference = render(1.0);
        let mean = reference.data().iter().sum::<f32>() / reference.data().len() as f32;
        assert!(mean > 0.01, "case {case}: the view at scale 1 is black");
        let exponent = [-100, -60, -20, 20, 60, 100][case as usize % 6];
        let other = render(2f64.powi(exponent));
        assert!(
            other.data().iter().all(|v| v.is_finite()),
            "case {case}, depth x2^{exponent}: not finite"
        );
        // Compared whole, not printed: a mismatch names the case, not 9216 values.
        assert!(
            other == reference,
            "case {case}, offset {offset:?}, depth x2^{exponent}: another picture"
        );
    }
}
