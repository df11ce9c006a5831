//! Unit tests of `reshade::net::lobes`, beside it so that the module file holds the code only.

use super::*;

fn spec(lobes: usize, deadzone: f32) -> LobeSpec {
    LobeSpec {
        lobes,
        deadzone,
        slide: false,
        domain: LobeDomain::Display,
    }
}

/// One lobe and the sliding layer, no dead zone.
fn slide_spec() -> LobeSpec {
    LobeSpec {
        slide: true,
        ..spec(1, 0.0)
    }
}

/// One pixel straight ahead at depth 1 (d = 0.25), one lobe around the input camera's
/// direction (0, 0, −1), sharpness 50, amplitude (0.4, 0.2, −0.2); camera (0.3, 0, 0):
/// w = normalize(0.3, 0, −1), so μ·w = 1/√1.09 and the change is
/// a · (exp(50 (1/√1.09 − 1)) − 1) (model.py's test_shade_lobes_is_the_closed_form).
#[test]
fn the_closed_form_matches_hand_computed_values() {
    let lobes = [0.0, 0.0, -1.0, 50.0, 0.4, 0.2, -0.2];
    let field = LobeField::new(
        spec(1, 0.0),
        1,
        1,
        &lobes,
        &[0.5; 3],
        &[0.25],
        &[0.0, 0.0, 1.0],
    )
    .unwrap();
    let drop = (50.0 * (1.0 / 1.09f64.sqrt() - 1.0)).exp() - 1.0;
    let expected = [0.4 * drop, 0.2 * drop, -0.2 * drop];
    let got = field.change([0.3, 0.0, 0.0], 1);
    for c in 0..3 {
        assert!(
            (f64::from(got[c]) - expected[c]).abs() < 1e-6,
            "{got:?} vs {expected:?}"
        );
    }
    // drop = e^(50·(0.957826 − 1)) − 1 ≈ −0.8786: a clear change, and the input
    // camera gives none at all.
    assert!((drop + 0.8786).abs() < 1e-4, "{drop}");
    assert_eq!(field.change([0.0; 3], 1), [0.0; 3]);
    let mut photo = SrgbImage::new(1, 1);
    photo.put(0, 0, [0.5, 0.5, 0.5]);
    let view = field.reshade(&photo, [0.3, 0.0, 0.0], 1).unwrap();
    let v = view.get(0, 0);
    assert!((f64::from(v[0]) - (0.5 + 0.4 * drop)).abs() < 1e-6, "{v:?}");
    assert!((f64::from(v[2]) - (0.5 - 0.2 * drop)).abs() < 1e-6, "{v:?}");
}

/// The same pixel and camera in the linear-clamped domain, where a lobe holds at most its
/// pixel's light: a lobe at the photo's view with amplitude a ≥ L (L = 0.5^2.2) is scaled
/// to L, so the view is L·G in linear light, 0.5·G^(1/2.2) displayed, whatever a. Where the
/// photo clipped (1.0) the lobe may be brighter than white: a = 4 keeps its 4, and the view
/// is min(4·G, 1) in linear light.
#[test]
fn the_linear_clamped_domain_never_takes_more_than_the_pixel_has() {
    let clamped = LobeSpec {
        domain: LobeDomain::LinearClamped,
        ..spec(1, 0.0)
    };
    let g = (50.0 * (1.0 / 1.09f64.sqrt() - 1.0)).exp();
    for (photo, amp, want) in [
        (0.5f32, 1.0f32, 0.5 * g.powf(1.0 / 2.2)),
        (0.5, 30.0, 0.5 * g.powf(1.0 / 2.2)),
        (1.0, 1.0, g.powf(1.0 / 2.2)),
        (1.0, 4.0, (4.0 * g).min(1.0).powf(1.0 / 2.2)),
    ] {
        let lobes = [0.0, 0.0, -1.0, 50.0, amp, amp, amp];
        let field = LobeField::new(
            clamped,
            1,
            1,
            &lobes,
            &[photo; 3],
            &[0.25],
            &[0.0, 0.0, 1.0],
        )
        .unwrap();
        assert_eq!(
            field.change([0.0; 3], 1),
            [0.0; 3],
            "photo {photo}, a {amp}"
        );
        let got = field.change([0.3, 0.0, 0.0], 1);
        for c in got {
            let view = f64::from(photo + c);
            assert!(
                (view - want).abs() < 1e-5,
                "photo {photo}, a {amp}: {view} vs {want}"
            );
        }
    }
}

#[test]
fn two_lobes_add_and_the_dead_zone_soft_thresholds() {
    // A pixel at depth 2 (d = 0.125) to the right of the axis; lobe 1 around the
    // input direction, lobe 2 broad around the optical axis towards the camera.
    let ray = [0.2f32, -0.1, 1.0];
    let d = 0.125f32;
    let n = (0.2f64 * 0.2 + 0.1 * 0.1 + 1.0).sqrt();
    let w0 = [-0.2 / n, 0.1 / n, -1.0 / n];
    let mut lobes = vec![
        w0[0] as f32,
        w0[1] as f32,
        w0[2] as f32,
        200.0,
        0.3,
        0.1,
        0.0,
    ];
    lobes.extend_from_slice(&[0.0, 0.0, -1.0, 2.0, 0.0, 0.05, -0.5]);
    // At 1x1 the channel-planar layout is the lobes' own order.
    let c = [0.1, 0.05, -0.2];
    // By hand, in f64: v = (d/0.25)·c − r.
    let q = f64::from(d) / 0.25;
    let v = [q * c[0] - 0.2, q * c[1] + 0.1, q * c[2] - 1.0];
    let vn = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let w = v.map(|x| x / vn);
    let dot = |mu: [f64; 3], w: [f64; 3]| mu[0] * w[0] + mu[1] * w[1] + mu[2] * w[2];
    // The lobe's axis as the field holds it (f32), so that only arithmetic differs.
    let mu1 = w0.map(|x| f64::from(x as f32));
    let mu2 = [0.0, 0.0, -1.0];
    let g = |mu, lambda: f64, w| (lambda * (dot(mu, w) - 1.0)).exp();
    let d1 = g(mu1, 200.0, w) - g(mu1, 200.0, w0);
    let d2 = g(mu2, 2.0, w) - g(mu2, 2.0, w0);
    let change = [0.3 * d1, 0.1 * d1 + 0.05 * d2, -0.5 * d2];
    for t in [0.0f32, 0.004, 0.05] {
        let field = LobeField::new(spec(2, t), 1, 1, &lobes, &[0.5; 3], &[d], &ray).unwrap();
        let got = field.change(c, 1);
        for ch in 0..3 {
            let x = change[ch];
            let t = f64::from(t);
            let want = if x > t {
                x - t
            } else if x < -t {
                x + t
            } else {
                0.0
            };
            assert!(
                (f64::from(got[ch]) - want).abs() < 1e-5,
                "dead zone {t}, channel {ch}: {} vs {want} (change {x})",
                got[ch]
            );
        }
    }
}

#[test]
fn the_sky_is_seen_along_its_ray_from_any_camera() {
    // Disparity 0: w = normalize(−r) whatever the camera, so nothing changes.
    let lobes = [0.0, 0.0, -1.0, 5.0, 1.0, 1.0, 1.0];
    let field = LobeField::new(
        spec(1, 0.0),
        1,
        1,
        &lobes,
        &[0.5; 3],
        &[0.0],
        &[0.3, 0.1, 1.0],
    )
    .unwrap();
    assert_eq!(field.change([0.4, -0.2, 0.3], 1), [0.0; 3]);
}

#[test]
fn rays_follow_the_scaled_intrinsics_with_integer_pixel_centres() {
    // A 640x480 photo, 90° horizontal field of view: fx = 320, centre (320, 240) in the
    // runtime's convention (pixel i centred at i + 0.5), (319.5, 239.5) in OpenCV's.
    let camera = Intrinsics::from_hfov(640, 480, 90.0);
    let rays = pixel_rays(&camera, 640, 480);
    let plane = 640 * 480;
    assert!((rays[0] - (-319.5 / 320.0)).abs() < 1e-6);
    assert!((rays[plane] - (-239.5 / 320.0)).abs() < 1e-6);
    assert_eq!(rays[2 * plane], 1.0);
    // At half size: fx 160, cx = 320·0.5 − 0.5 = 159.5, so pixel 159.5 is the axis.
    let half = pixel_rays(&camera, 320, 240);
    let p = 320 * 240;
    assert!((half[159] + half[160]).abs() < 1e-6);
    assert!((half[p + 119 * 320] + half[p + 120 * 320]).abs() < 1e-6);
    assert!((half[0] - (-159.5 / 160.0)).abs() < 1e-6);
}

#[test]
fn wrong_sizes_are_refused() {
    let msg = LobeField::new(
        spec(2, 0.0),
        2,
        2,
        &[0.0; 7 * 4],
        &[0.0; 12],
        &[0.0; 4],
        &[0.0; 12],
    )
    .unwrap_err()
    .to_string();
    assert!(msg.contains("lobes") && msg.contains("56"), "{msg}");
    let field = LobeField::new(
        spec(1, 0.0),
        2,
        1,
        &[0.0; 14],
        &[0.0; 6],
        &[0.0; 2],
        &[0.0; 6],
    )
    .unwrap();
    let msg = field
        .reshade(&SrgbImage::new(3, 1), [0.1, 0.0, 0.0], 1)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("3x1") && msg.contains("2x1"), "{msg}");
}

/// A row of 9 pixels at depth 1 (d = 0.25), rays 0.1 apart (fx = 10 px), one lobe of zero
/// amplitude and a sliding layer that is all of a photo with one bright pixel at x = 4.
fn slide_row(rho: f32) -> LobeField {
    let (w, plane) = (9usize, 9usize);
    let mut lobes = vec![0.0f32; (7 + 4) * plane];
    for i in 0..plane {
        lobes[2 * plane + i] = -1.0; // μ_z
        lobes[3 * plane + i] = 10.0; // λ
        for c in 0..3 {
            lobes[(7 + c) * plane + i] = 1.0; // the whole photo slides
        }
        lobes[10 * plane + i] = rho;
    }
    let mut image = vec![0.1f32; 3 * plane];
    for c in 0..3 {
        image[c * plane + 4] = 0.9;
    }
    let mut rays = vec![1.0f32; 3 * plane];
    for x in 0..w {
        rays[x] = (x as f32 - 4.0) / 10.0;
        rays[plane + x] = 0.0;
    }
    LobeField::new(slide_spec(), w, 1, &lobes, &image, &[0.25; 9], &rays).unwrap()
}

#[test]
fn a_reflection_at_infinity_slides_by_the_surface_s_parallax() {
    // ρ = 1: the layer is at infinity, p(0) − p(1) = tx, so a camera 0.2 to the right
    // shifts it by 0.2 · 10 = 2 px across a surface at depth 1 (model.py's
    // test_slide_moves_a_highlight_by_its_layer_s_parallax).
    let field = slide_row(1.0);
    let change = field.change([0.2, 0.0, 0.0], 1);
    let red: Vec<f32> = change.chunks_exact(3).map(|px| px[0]).collect();
    for (x, &v) in red.iter().enumerate() {
        let want = match x {
            4 => -0.8,
            6 => 0.8,
            _ => 0.0,
        };
        assert!((v - want).abs() < 1e-5, "x {x}: {v} vs {want} ({red:?})");
    }
    // The input camera: exactly the photo, to the bit.
    assert!(field.change([0.0; 3], 2).iter().all(|&v| v == 0.0));
}

#[test]
fn a_layer_on_the_surface_never_moves() {
    let field = slide_row(0.0);
    for c in [[0.3, 0.0, 0.0], [-0.2, 0.1, 0.4]] {
        assert!(field.change(c, 1).iter().all(|&v| v.abs() < 1e-6), "{c:?}");
    }
}

#[test]
fn a_slide_field_needs_its_four_extra_channels() {
    let spec = slide_spec();
    assert_eq!(spec.channels(), 11);
    let msg = LobeField::new(spec, 1, 1, &[0.0; 7], &[0.0; 3], &[0.0], &[0.0; 3])
        .unwrap_err()
        .to_string();
    assert!(msg.contains("11 planes"), "{msg}");
}
