//! The network reshader on the committed fixture model: output shapes and padding,
//! encoder+decoder against the single graph, determinism across thread counts and
//! parallel views, the per-view cost options, and the other precisions.

use crate::reshade_support;

use reshade_support::{manifest_path, max_abs_diff, scene, tract};
use reshader::engine::manifest::{Precision, Task};
use reshader::io::photo::SrgbImage;
use reshader::reshade::net::{NetOptions, NetReshader};
use reshader::reshade::Reshader;

const CAMERA: [f64; 3] = [0.12, -0.05, 0.2];

fn single(threads: usize, options: NetOptions) -> NetReshader {
    let path = manifest_path(Task::Reshade, Precision::Fp32);
    NetReshader::load(&path, Precision::Fp32, tract(threads), options).unwrap()
}

fn split(threads: usize, options: NetOptions) -> NetReshader {
    let path = manifest_path(Task::ReshadeEncoder, Precision::Fp32);
    NetReshader::load(&path, Precision::Fp32, tract(threads), options).unwrap()
}

fn reshade(net: &NetReshader, image: &SrgbImage, centres: &[[f64; 3]]) -> Vec<SrgbImage> {
    let (_, depth) = scene(image.width(), image.height());
    net.prepare_photo(image, &depth)
        .unwrap()
        .reshade_views(centres)
        .unwrap()
}

#[test]
fn output_has_the_photo_size_whatever_the_padding() {
    let net = split(1, NetOptions::default());
    for (w, h) in [(64, 32), (50, 37), (33, 70)] {
        let (image, depth) = scene(w, h);
        let prepared = net.prepare_photo(&image, &depth).unwrap();
        let (pw, ph) = prepared.network_size();
        assert_eq!((pw % 32, ph % 32), (0, 0));
        assert!(
            pw >= w as usize && pw < w as usize + 32 && ph >= h as usize && ph < h as usize + 32
        );
        let out = prepared.reshade_views(&[CAMERA]).unwrap().remove(0);
        assert_eq!((out.width(), out.height()), (w, h));
        assert!(out.data().iter().all(|v| (0.0..=1.0).contains(v)));
    }
}

#[test]
fn padding_replicates_the_edges_and_is_cropped_away() {
    // A 50x37 photo, and the same photo replicate-padded by hand to 64x64: the network
    // sees identical inputs, so the small result is exactly the big one's top-left.
    let net = split(1, NetOptions::default());
    let (small, small_depth) = scene(50, 37);
    let mut big = SrgbImage::new(64, 64);
    let mut big_depth = Vec::with_capacity(64 * 64);
    for y in 0..64u32 {
        for x in 0..64u32 {
            let (sx, sy) = (x.min(49), y.min(36));
            big.put(x, y, small.get(sx, sy));
            big_depth.push(small_depth.at(sx as usize, sy as usize));
        }
    }
    let big_depth = reshader::depth::DepthMap::new(64, 64, big_depth);
    let a = net
        .prepare_photo(&small, &small_depth)
        .unwrap()
        .reshade_views(&[CAMERA])
        .unwrap();
    let b = net
        .prepare_photo(&big, &big_depth)
        .unwrap()
        .reshade_views(&[CAMERA])
        .unwrap();
    for y in 0..37 {
        for x in 0..50 {
            assert_eq!(a[0].get(x, y), b[0].get(x, y), "pixel {x},{y}");
        }
    }
}

#[test]
fn encoder_and_decoder_equal_the_single_graph() {
    let (image, _) = scene(96, 64);
    let centres = [CAMERA, [-0.2, 0.0, 0.0], [0.0, 0.1, -0.1]];
    let a = reshade(&single(1, NetOptions::default()), &image, &centres);
    let b = reshade(&split(1, NetOptions::default()), &image, &centres);
    for (x, y) in a.iter().zip(&b) {
        let d = max_abs_diff(x, y);
        assert!(d < 1e-5, "split and single graphs differ by {d}");
    }
    // And the camera matters: the views differ from one another.
    assert!(max_abs_diff(&a[0], &a[1]) > 1e-4);
}

#[test]
fn results_do_not_depend_on_thread_count_or_parallel_views() {
    let (image, _) = scene(96, 64);
    let centres = [CAMERA, [-0.2, 0.0, 0.0], [0.1, 0.0, 0.0]];
    let one = reshade(&split(1, NetOptions::default()), &image, &centres);
    let two = reshade(&split(2, NetOptions::default()), &image, &centres);
    let parallel = NetOptions {
        parallel_views: 2,
        ..Default::default()
    };
    let par = reshade(&split(1, parallel), &image, &centres);
    for i in 0..centres.len() {
        assert_eq!(one[i], two[i], "view {i}: 1 vs 2 kernel threads");
        assert_eq!(one[i], par[i], "view {i}: sequential vs parallel views");
    }
}

#[test]
fn plans_are_cached_per_resolution_and_reused() {
    let net = split(1, NetOptions::default());
    let (image, _) = scene(64, 32);
    let first = reshade(&net, &image, &[CAMERA]);
    let (other, _) = scene(96, 64);
    reshade(&net, &other, &[CAMERA]);
    assert_eq!(reshade(&net, &image, &[CAMERA]), first);
}

#[test]
fn batching_views_gives_the_same_images() {
    let (image, _) = scene(64, 32);
    let centres = [CAMERA, [-0.2, 0.0, 0.0], [0.1, 0.0, 0.0]];
    let plain = reshade(&split(1, NetOptions::default()), &image, &centres);
    let batched = reshade(
        &split(
            1,
            NetOptions {
                batch: 2,
                ..Default::default()
            },
        ),
        &image,
        &centres,
    );
    for (a, b) in plain.iter().zip(&batched) {
        assert!(max_abs_diff(a, b) < 1e-5);
    }
}

#[test]
fn key_views_are_exact_and_views_between_them_blend() {
    let (image, _) = scene(64, 32);
    let centres: Vec<[f64; 3]> = (0..5).map(|i| [-0.2 + 0.1 * i as f64, 0.0, 0.0]).collect();
    // At full working size, and at half, where the key views' residuals are upsampled.
    for scale in [1.0, 0.5] {
        let options = |key_views| NetOptions {
            key_views,
            scale,
            ..Default::default()
        };
        let plain = reshade(&split(1, options(None)), &image, &centres);
        let keyed = reshade(&split(1, options(Some(3))), &image, &centres);
        for i in [0, 2, 4] {
            assert_eq!(plain[i], keyed[i], "scale {scale}: key view {i}");
        }
        // View 1 lies halfway between keys 0 and 2: its residual is their mean.
        let (a, b) = (&plain[0], &plain[2]);
        for (k, v) in keyed[1].data().iter().enumerate() {
            let (x, y, p) = (a.data()[k], b.data()[k], image.data()[k]);
            let unclamped = p + 0.5 * ((x - p) + (y - p));
            if (0.01..0.99).contains(&unclamped) {
                assert!((v - unclamped).abs() < 1e-5, "scale {scale}");
            }
        }
    }
}

#[test]
fn reduced_working_resolution_keeps_the_photo_size_and_detail() {
    let (image, _) = scene(96, 64);
    let full = reshade(&split(1, NetOptions::default()), &image, &[CAMERA]).remove(0);
    let half = reshade(
        &split(
            1,
            NetOptions {
                scale: 0.5,
                ..Default::default()
            },
        ),
        &image,
        &[CAMERA],
    )
    .remove(0);
    assert_eq!((half.width(), half.height()), (96, 64));
    // The photo's own detail survives (only the residual is upsampled), so the result is
    // close to the full-resolution one, and closer to it than a blurred photo would be.
    let d = max_abs_diff(&full, &half);
    assert!(d < 0.25, "half-resolution residual differs by {d}");
    let mean: f32 = full
        .data()
        .iter()
        .zip(half.data())
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>()
        / full.data().len() as f32;
    assert!(mean < 0.02, "mean difference {mean}");
}

#[test]
fn a_longest_side_limit_is_the_same_reduction_as_the_scale_it_implies() {
    let (image, _) = scene(96, 64);
    let options = |scale, max_side| NetOptions {
        scale,
        max_side,
        ..Default::default()
    };
    let half = reshade(&split(1, options(0.5, None)), &image, &[CAMERA]);
    let limited = reshade(&split(1, options(1.0, Some(48))), &image, &[CAMERA]);
    assert_eq!(half, limited);
    // A limit above the photo's size leaves it at its own size, as no limit does.
    let full = reshade(&split(1, options(1.0, None)), &image, &[CAMERA]);
    let roomy = reshade(&split(1, options(1.0, Some(500))), &image, &[CAMERA]);
    assert_eq!(full, roomy);
    assert_ne!(full, half);
}

#[test]
fn far_cameras_are_reshaded_at_the_trained_distance() {
    let (image, _) = scene(64, 32);
    let net = split(1, NetOptions::default());
    let views = reshade(&net, &image, &[[0.3, 0.0, 0.0], [0.9, 0.0, 0.0]]);
    assert_eq!(views[0], views[1]);
    let unlimited = split(
        1,
        NetOptions {
            max_offset: Some(10.0),
            ..Default::default()
        },
    );
    let views = reshade(&unlimited, &image, &[[0.3, 0.0, 0.0], [0.9, 0.0, 0.0]]);
    assert_ne!(views[0], views[1]);
}

#[test]
fn the_reshader_trait_runs_the_network() {
    let net = split(1, NetOptions::default());
    let (image, depth) = scene(64, 32);
    let direct = net
        .prepare_photo(&image, &depth)
        .unwrap()
        .reshade_views(&[CAMERA])
        .unwrap();
    let reshader: &dyn Reshader = &net;
    let camera = reshader::views::Intrinsics::from_hfov(64, 32, 60.0);
    let via_trait = reshader
        .prepare(&image, &depth, &camera)
        .unwrap()
        .reshade(CAMERA)
        .unwrap();
    assert_eq!(direct[0], via_trait);
    // The description names the weights by checksum, so a retrained model with the same
    // name and version is told apart (the gallery's done-markers rely on it).
    let sha = |file: &str| -> String {
        let text = std::fs::read_to_string(format!("models/fixtures/{file}")).unwrap();
        let manifest: serde_json::Value = serde_json::from_str(&text).unwrap();
        manifest["sha256"].as_str().unwrap()[..12].to_owned()
    };
    let description = reshader.description();
    let encoder = sha("reshade-fixture-fp32-encoder.json");
    let decoder = sha("reshade-fixture-fp32-decoder.json");
    assert!(
        description.contains(&format!("encoder {encoder} + decoder {decoder}")),
        "{description}"
    );
}

#[test]
fn depth_of_another_size_is_refused() {
    let net = split(1, NetOptions::default());
    let (image, _) = scene(64, 32);
    let (_, depth) = scene(32, 32);
    let msg = net.prepare_photo(&image, &depth).err().unwrap().to_string();
    assert!(msg.contains("32x32") && msg.contains("64x32"), "{msg}");
}

#[test]
fn fp16_storage_computes_close_to_fp32() {
    let (image, _) = scene(96, 64);
    let fp32 = reshade(&split(1, NetOptions::default()), &image, &[CAMERA]).remove(0);
    let path = manifest_path(Task::ReshadeEncoder, Precision::Fp16);
    let net = NetReshader::load(&path, Precision::Fp16, tract(1), NetOptions::default()).unwrap();
    let fp16 = reshade(&net, &image, &[CAMERA]).remove(0);
    let d = max_abs_diff(&fp32, &fp16);
    assert!(d < 1e-2, "fp16 weights change the output by {d}");
}

#[test]
fn int8_runs_through_tract_close_to_fp32() {
    let (image, _) = scene(96, 64);
    let fp32 = reshade(&split(1, NetOptions::default()), &image, &[CAMERA]).remove(0);
    let path = manifest_path(Task::ReshadeEncoder, Precision::Int8);
    let net = NetReshader::load(&path, Precision::Int8, tract(1), NetOptions::default()).unwrap();
    let int8 = reshade(&net, &image, &[CAMERA]).remove(0);
    let d = max_abs_diff(&fp32, &int8);
    assert!(d < 0.1, "int8 output differs from fp32 by {d}");
}

// --- the lobe head ----------------------------------------------------------------------------

mod lobes {
    use super::*;
    use reshader::reshade::net::lobes::LobeReshader;
    use reshader::views::Intrinsics;

    fn lobe_net(threads: usize, options: NetOptions) -> LobeReshader {
        let path = manifest_path(Task::ReshadeLobes, Precision::Fp32);
        LobeReshader::load(&path, Precision::Fp32, tract(threads), options).unwrap()
    }

    fn camera(image: &SrgbImage) -> Intrinsics {
        Intrinsics::from_hfov(image.width(), image.height(), 60.0)
    }

    #[test]
    fn any_photo_size_gives_a_view_of_that_size_and_the_photo_at_camera_zero() {
        let net = lobe_net(1, NetOptions::default());
        for (w, h) in [(64, 32), (50, 37), (33, 70)] {
            let (image, depth) = scene(w, h);
            let prepared = net.prepare_photo(&image, &depth, &camera(&image)).unwrap();
            let (pw, ph) = prepared.network_size();
            assert_eq!((pw % 32, ph % 32), (0, 0));
            let out = prepared.reshade_view(CAMERA).unwrap();
            assert_eq!((out.width(), out.height()), (w, h));
            assert!(out.data().iter().all(|v| (0.0..=1.0).contains(v)));
            assert_ne!(out, image, "{w}x{h}: the fixture's lobes change the view");
            assert_eq!(prepared.reshade_view([0.0; 3]).unwrap(), image);
        }
    }

    #[test]
    fn views_do_not_depend_on_the_thread_count() {
        let (image, depth) = scene(96, 64);
        let cam = camera(&image);
        let one = lobe_net(1, NetOptions::default());
        let two = lobe_net(2, NetOptions::default());
        let a = one.prepare_photo(&image, &depth, &cam).unwrap();
        let b = two.prepare_photo(&image, &depth, &cam).unwrap();
        for centre in [CAMERA, [-0.5, 0.0, 0.0], [0.0, 0.3, -0.4]] {
            assert_eq!(
                a.reshade_view(centre).unwrap(),
                b.reshade_view(centre).unwrap()
            );
        }
    }

    #[test]
    fn a_reduced_working_resolution_upsamples_the_change() {
        let (image, depth) = scene(96, 64);
        let cam = camera(&image);
        let full = lobe_net(1, NetOptions::default());
        let half = lobe_net(
            2,
            NetOptions {
                scale: 0.5,
                ..Default::default()
            },
        );
        let a = full.prepare_photo(&image, &depth, &cam).unwrap();
        let b = half.prepare_photo(&image, &depth, &cam).unwrap();
        assert_eq!(b.network_size(), (64, 32));
        assert_eq!((b.field().width(), b.field().height()), (48, 32));
        assert_eq!(b.reshade_view([0.0; 3]).unwrap(), image);
        let (va, vb) = (
            a.reshade_view(CAMERA).unwrap(),
            b.reshade_view(CAMERA).unwrap(),
        );
        assert_eq!((vb.width(), vb.height()), (96, 64));
        assert_ne!(vb, image);
        // The same network at half the resolution: close to the full-resolution view,
        // not equal to it.
        let d = max_abs_diff(&va, &vb);
        assert!(d > 0.0 && d < 0.5, "{d}");
    }

    #[test]
    fn offsets_beyond_the_trained_range_are_kept_unless_limited() {
        let (image, depth) = scene(64, 32);
        let cam = camera(&image);
        let far = [0.9, 0.0, 0.0];
        let free = lobe_net(1, NetOptions::default());
        let limited = lobe_net(
            1,
            NetOptions {
                max_offset: Some(0.3),
                ..Default::default()
            },
        );
        let a = free.prepare_photo(&image, &depth, &cam).unwrap();
        let b = limited.prepare_photo(&image, &depth, &cam).unwrap();
        assert_ne!(
            a.reshade_view(far).unwrap(),
            a.reshade_view([0.3, 0.0, 0.0]).unwrap()
        );
        assert_eq!(
            b.reshade_view(far).unwrap(),
            a.reshade_view([0.3, 0.0, 0.0]).unwrap()
        );
        assert!(limited.description().contains("offsets limited to 0.3"));
    }

    #[test]
    fn the_reshader_trait_runs_the_lobe_head_and_names_it() {
        let net = lobe_net(2, NetOptions::default());
        let (image, depth) = scene(64, 32);
        let cam = camera(&image);
        let direct = net
            .prepare_photo(&image, &depth, &cam)
            .unwrap()
            .reshade_view(CAMERA)
            .unwrap();
        let reshader: &dyn Reshader = &net;
        let via_trait = reshader
            .prepare(&image, &depth, &cam)
            .unwrap()
            .reshade_all(&[CAMERA, [0.0; 3]])
            .unwrap();
        assert_eq!(via_trait, vec![direct, image.clone()]);
        let d = reshader.description();
        let text =
            std::fs::read_to_string(manifest_path(Task::ReshadeLobes, Precision::Fp32)).unwrap();
        let m: serde_json::Value = serde_json::from_str(&text).unwrap();
        let sha = &m["sha256"].as_str().unwrap()[..12];
        assert!(
            d.contains("head lobes") && d.contains("2 lobes") && d.contains(sha),
            "{d}"
        );
        assert!(d.contains("reshade-fixture-fp32-lobes"), "{d}");
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let net = lobe_net(1, NetOptions::default());
        let (image, _) = scene(64, 32);
        let (_, depth) = scene(32, 32);
        let msg = net
            .prepare_photo(&image, &depth, &camera(&image))
            .err()
            .unwrap()
            .to_string();
        assert!(msg.contains("32x32") && msg.contains("64x32"), "{msg}");
        let (image, depth) = scene(64, 32);
        let other = Intrinsics::from_hfov(128, 64, 60.0);
        let msg = net
            .prepare_photo(&image, &depth, &other)
            .err()
            .unwrap()
            .to_string();
        assert!(msg.contains("128x64") && msg.contains("64x32"), "{msg}");
        let mut zero = camera(&image);
        zero.fx = 0.0;
        assert!(net.prepare_photo(&image, &depth, &zero).is_err());
        let empty = SrgbImage::new(0, 0);
        let none = reshader::depth::DepthMap::new(0, 0, Vec::new());
        let msg = net
            .prepare_photo(&empty, &none, &camera(&empty))
            .err()
            .unwrap()
            .to_string();
        assert!(msg.contains("0x0"), "{msg}");
    }
}

#[test]
fn a_view_changed_at_too_few_pixels_keeps_the_photo() {
    let (image, _) = scene(64, 32);
    let gated = |gate| {
        let options = NetOptions {
            gate,
            ..Default::default()
        };
        reshade(&split(1, options), &image, &[CAMERA]).remove(0)
    };
    let predicted = gated(0.0);
    let pixels = image.data().len() / 3;
    let changed = predicted
        .data()
        .chunks_exact(3)
        .zip(image.data().chunks_exact(3))
        .filter(|(v, p)| v.iter().zip(*p).any(|(a, b)| (a - b).abs() > 1.0 / 255.0))
        .count();
    let share = changed as f64 / pixels as f64;
    assert!(
        share > 0.0 && share < 1.0,
        "the fixture must change some pixels and not all: {share}"
    );
    assert_eq!(gated(share * 0.99), predicted);
    assert_eq!(gated(share * 1.01 + 1e-9), image);
}

#[test]
fn a_gate_outside_zero_to_one_is_refused() {
    for gate in [-0.1, 1.5, f64::NAN] {
        let path = manifest_path(Task::ReshadeEncoder, Precision::Fp32);
        let options = NetOptions {
            gate,
            ..Default::default()
        };
        let err = NetReshader::load(&path, Precision::Fp32, tract(1), options)
            .err()
            .expect("refused");
        assert!(err.to_string().contains("reshade gate"), "{err}");
    }
}
