//! Unit tests of `relocate`, beside it so that the module file holds the code only.

use super::*;
use image::RgbImage;

const W: u32 = 48;
const H: u32 = 32;
const FOCUS: f64 = 2.0;

fn camera() -> Intrinsics {
    Intrinsics::from_hfov(W, H, 60.0)
}

fn textured() -> SrgbImage {
    let mut img = SrgbImage::new(W, H);
    for y in 0..H {
        for x in 0..W {
            img.put(
                x,
                y,
                [
                    x as f32 / W as f32,
                    y as f32 / H as f32,
                    ((x * 7 + y * 3) % 5) as f32 / 4.0,
                ],
            );
        }
    }
    img
}

fn view(tx: f64) -> ViewCamera {
    ViewCamera::off_axis(&camera(), [tx, 0.0, 0.0], FOCUS).unwrap()
}

const RED: [f32; 3] = [1.0, 0.0, 0.0];
const BLUE: [f32; 3] = [0.0, 0.0, 1.0];

/// A red square at depth 1 in front of a blue wall at depth 4.
fn square_scene() -> (SrgbImage, DepthMap) {
    let mut img = SrgbImage::new(W, H);
    let mut depth = vec![4.0f32; (W * H) as usize];
    for y in 0..H {
        for x in 0..W {
            let inside = (18..30).contains(&x) && (10..22).contains(&y);
            img.put(x, y, if inside { RED } else { BLUE });
            if inside {
                depth[(y * W + x) as usize] = 1.0;
            }
        }
    }
    (img, DepthMap::new(W as usize, H as usize, depth))
}

fn red_columns(img: &SrgbImage, y: u32) -> Vec<u32> {
    (0..W).filter(|&x| img.get(x, y) == RED).collect()
}

#[test]
fn plane_at_focus_is_unchanged_in_every_view() {
    let img = textured();
    let depth = DepthMap::new(W as usize, H as usize, vec![FOCUS as f32; (W * H) as usize]);
    let views = [-0.3, -0.05, 0.0, 0.2].map(view).into_iter().chain([
        ViewCamera::off_axis(&camera(), [0.1, -0.05, 0.3], FOCUS).unwrap(),
        ViewCamera::off_axis(&camera(), [0.0, 0.0, -0.5], FOCUS).unwrap(),
    ]);
    for cam in views {
        let out = MeshWarp::default()
            .render(&img, &depth, &camera(), &cam)
            .unwrap();
        for (i, (a, b)) in out.data().iter().zip(img.data()).enumerate() {
            assert!((a - b).abs() < 1e-5, "{:?} at {i}: {a} vs {b}", cam.centre);
        }
    }
}

#[test]
fn near_square_moves_against_the_camera() {
    let (img, depth) = square_scene();
    let before = red_columns(&img, 16);
    let right = MeshWarp::default()
        .render(&img, &depth, &camera(), &view(0.1))
        .unwrap();
    let left = MeshWarp::default()
        .render(&img, &depth, &camera(), &view(-0.1))
        .unwrap();
    let (r, l) = (red_columns(&right, 16), red_columns(&left, 16));
    // Parallax of a point at depth 1 with the plane at 2: f · tx · (1/1 − 1/2).
    let shift = camera().fx * 0.1 * 0.5;
    assert!(shift > 2.0);
    let mean = |v: &[u32]| v.iter().sum::<u32>() as f64 / v.len() as f64;
    assert!((mean(&r) - (mean(&before) - shift)).abs() < 1.0, "{r:?}");
    assert!((mean(&l) - (mean(&before) + shift)).abs() < 1.0, "{l:?}");
    // The mesh spans pixel centres, so a cut-out object may lose up to one pixel.
    assert!(
        (before.len() - 1..=before.len()).contains(&r.len()),
        "{r:?}"
    );
}

#[test]
fn disocclusions_are_filled_with_background() {
    let (img, depth) = square_scene();
    let out = MeshWarp::default()
        .render(&img, &depth, &camera(), &view(0.15))
        .unwrap();
    let reds = red_columns(&out, 16);
    let right_edge = *reds.last().unwrap();
    // The square moved left: everything right of it, including what it covered, is wall.
    assert!(right_edge < 29);
    for x in right_edge + 1..W {
        assert_eq!(out.get(x, 16), BLUE, "x={x}");
    }
    // No colour between red and blue: the edge triangles were cut, not stretched.
    assert!(out.data().chunks(3).all(|p| p == RED || p == BLUE));
}

#[test]
fn disocclusion_fill_continues_the_background_texture() {
    let (mut img, depth) = square_scene();
    let stripe = |x: u32| if x % 2 == 0 { BLUE } else { [0.0, 1.0, 0.0] };
    for y in 0..H {
        for x in 0..W {
            if img.get(x, y) == BLUE {
                img.put(x, y, stripe(x));
            }
        }
    }
    let out = MeshWarp::default()
        .render(&img, &depth, &camera(), &view(0.15))
        .unwrap();
    let right_edge = *red_columns(&out, 16).last().unwrap();
    let revealed: Vec<[f32; 3]> = (right_edge + 1..29).map(|x| out.get(x, 16)).collect();
    assert!(revealed.len() >= 3, "{revealed:?}");
    // Wall colours (stripes blended by the sub-pixel shift), never the square's red.
    assert!(revealed.iter().all(|p| p[0] == 0.0), "{revealed:?}");
    assert!(
        revealed.windows(2).any(|w| w[0] != w[1]),
        "smeared: {revealed:?}"
    );
}

#[test]
fn mismatched_sizes_are_an_error() {
    let depth = DepthMap::new(4, 4, vec![1.0; 16]);
    let err = MeshWarp::default()
        .render(&SrgbImage::new(4, 3), &depth, &camera(), &view(0.0))
        .unwrap_err();
    assert!(matches!(err, RelocateError::SizeMismatch { .. }));
}

/// A square over a wall with a textured face, 8-bit as live frames are.
fn textured_square() -> (RgbImage, DepthMap) {
    let (_, depth) = square_scene();
    (textured().to_rgb8(), depth)
}

#[test]
fn ldi_view_maps_render_the_views_the_ldi_renders() {
    let (frame, depth) = textured_square();
    let colours = SrgbImage::from_rgb8(&frame);
    // As `live` builds it: a soft pixel is a blend and a smoothed band sample a copy
    // plus an offset, which a lookup cannot express.
    let relocator = LdiRelocator::new(LdiConfig {
        silhouettes: Silhouettes::Hard,
        band_smoothing: 0,
        ..LdiConfig::default()
    });
    let cameras = [view(-0.3), view(0.0), view(0.25)];
    let prepared = relocator
        .prepare(&colours, &depth, &camera(), &cameras)
        .unwrap();
    let mut mapped = RgbImage::new(0, 0);
    for cam in &cameras {
        let rendered = prepared.render(&colours, cam).unwrap().to_rgb8();
        let map = prepared.view_map(cam).expect("the LDI gives maps");
        map.apply(&frame, None, &mut mapped).unwrap();
        let worst = rendered
            .as_raw()
            .iter()
            .zip(mapped.as_raw())
            .map(|(&a, &b)| a.abs_diff(b))
            .max();
        assert_eq!(worst, Some(0), "camera {:?}", cam.centre);
    }
    // Reshading carried as a change: the same as rendering the reshaded colours.
    let mut reshaded = colours.clone();
    reshaded.put(20, 12, [1.0, 1.0, 1.0]);
    let change = map::ShadingChange::between(&colours, &reshaded).unwrap();
    let cam = &cameras[2];
    let rendered = prepared.render(&reshaded, cam).unwrap().to_rgb8();
    let map = prepared.view_map(cam).unwrap();
    map.apply(&frame, Some(&change), &mut mapped).unwrap();
    assert_eq!(rendered.as_raw(), mapped.as_raw());
}

#[test]
fn inpainted_borders_soft_silhouettes_and_a_smoothed_band_give_no_view_map() {
    let (frame, depth) = textured_square();
    let colours = SrgbImage::from_rgb8(&frame);
    let hard = LdiConfig {
        silhouettes: Silhouettes::Hard,
        band_smoothing: 0,
        ..LdiConfig::default()
    };
    let configs = [
        (hard.clone(), true),
        (
            LdiConfig {
                border: Border::Inpaint,
                ..hard.clone()
            },
            false,
        ),
        (
            LdiConfig {
                band_smoothing: 3,
                ..hard
            },
            false,
        ),
        (LdiConfig::default(), false),
    ];
    for (config, maps) in configs {
        let relocator = LdiRelocator::new(config.clone());
        let prepared = relocator
            .prepare(&colours, &depth, &camera(), &[view(0.3)])
            .unwrap();
        assert_eq!(prepared.view_map(&view(0.3)).is_some(), maps, "{config:?}");
    }
}

#[test]
fn live_relocators_draw_hard_silhouettes_and_give_view_maps() {
    let (frame, depth) = textured_square();
    let colours = SrgbImage::from_rgb8(&frame);
    let relocator = RelocateConfig::default().build_live();
    let prepared = relocator
        .prepare(&colours, &depth, &camera(), &[view(0.3)])
        .unwrap();
    assert!(prepared.view_map(&view(0.3)).is_some());
}

#[test]
fn a_live_relocator_never_narrows_its_crop_framing() {
    let config = LdiConfig {
        border: Border::Crop,
        ..LdiConfig::default()
    };
    let colours = textured();
    let cameras = [view(-0.3), view(0.3)];
    let (_, deep) = square_scene();
    let flat = DepthMap::new(W as usize, H as usize, vec![FOCUS as f32; (W * H) as usize]);
    let render_flat = |relocator: &LdiRelocator| {
        relocator
            .prepare(&colours, &flat, &camera(), &cameras)
            .unwrap()
            .render(&colours, &cameras[1])
            .unwrap()
    };
    // A plane at the focus moves nowhere: fitted on its own it needs no crop.
    let each_photo = LdiRelocator::new(config.clone());
    each_photo
        .prepare(&colours, &deep, &camera(), &cameras)
        .unwrap();
    assert_eq!(render_flat(&each_photo), colours);
    // After a deep frame, a live stream keeps that frame's magnification.
    let live = LdiRelocator::steady(config);
    live.prepare(&colours, &deep, &camera(), &cameras).unwrap();
    assert_ne!(render_flat(&live), colours);
}

#[test]
fn the_plain_and_8_bit_renders_are_the_detailed_render_s_image() {
    let (frame, depth) = textured_square();
    let colours = SrgbImage::from_rgb8(&frame);
    for border in [Border::Crop, Border::Extend, Border::Inpaint] {
        let config = LdiConfig {
            border,
            ..LdiConfig::default()
        };
        let ldi = ldi::Ldi::build(&colours, &depth, &camera(), &config, 0.4).unwrap();
        for cam in [view(-0.4), view(0.1), view(0.35)] {
            let plain = ldi.render(&colours, &cam).unwrap();
            let detailed = ldi.render_detailed(&colours, &cam).unwrap();
            assert_eq!(plain.data(), detailed.image.data(), "{border:?}");
            let bytes = ldi.render_rgb8(&colours, &cam).unwrap();
            assert_eq!(bytes, plain.to_rgb8(), "{border:?}: the 8-bit render");
        }
    }
}
