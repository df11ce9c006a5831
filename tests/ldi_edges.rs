//! Golden tests of the depth-edge cases: each view is compared with the picture the
//! scene's geometry predicts (objects shifted by their exact parallax, what they uncover
//! showing the surface behind), pixel by pixel away from the predicted boundaries.

use crate::ldi_support;

use ldi_support::*;
use reshader::relocate::ldi::{Border, LdiConfig};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Label {
    Red,
    Green,
    Wall,
}

fn label(rgb: [f32; 3]) -> Label {
    if rgb[0] > 0.5 {
        Label::Red
    } else if rgb[1] > 0.9 && rgb[2] < 0.1 {
        Label::Green
    } else {
        Label::Wall
    }
}

/// Compares every pixel of `rows` whose centre is more than a pixel away from all of
/// `boundaries` (predicted x positions) with `expected(x)`.
fn assert_golden(
    image: &reshader::io::photo::SrgbImage,
    rows: std::ops::Range<usize>,
    boundaries: &[f64],
    expected: impl Fn(f64) -> Label,
) {
    for y in rows {
        for x in 0..W {
            let centre = x as f64 + 0.5;
            if boundaries.iter().any(|b| (centre - b).abs() < 1.0) {
                continue;
            }
            let got = label(image.get(x as u32, y as u32));
            assert_eq!(got, expected(centre), "pixel ({x}, {y})");
        }
    }
}

#[test]
fn thin_foreground_structures_keep_their_width_and_move_by_their_parallax() {
    let focus = 4.0;
    // A one-pixel pole at depth 1 and a two-pixel one at depth 1.5.
    let scene = Scene::wall(4.0)
        .rect(20..21, 4..44, RED, 1.0)
        .rect(40..42, 4..44, RED, 1.5);
    let ldi = scene.build(&LdiConfig::default(), 0.2);
    for tx in [-0.2, -0.07, 0.0, 0.13, 0.2] {
        let view = render(&ldi, &scene, tx, focus);
        for y in 8..40 {
            let row = red_row(&view.image, y);
            for (start, width, depth) in [(20.0, 1.0, 1.0), (40.0, 2.0, 1.5)] {
                let left = start + shift(tx, depth, focus);
                let window = (left.floor() as usize - 2)..(left + width).ceil() as usize + 2;
                let mass: f32 = row[window.clone()].iter().sum();
                let centroid: f32 = window
                    .clone()
                    .map(|x| (x as f32 + 0.5) * row[x])
                    .sum::<f32>()
                    / mass;
                assert!(
                    (mass - width as f32).abs() < 0.26,
                    "tx={tx} y={y}: {mass} px of pole, want {width}"
                );
                let want = (left + width / 2.0) as f32;
                assert!(
                    (centroid - want).abs() < 0.3,
                    "tx={tx} y={y}: pole at {centroid}, want {want}"
                );
            }
            let total: f32 = row.iter().sum();
            assert!(
                (total - 3.0).abs() < 0.5,
                "tx={tx} y={y}: red smeared: {total} px"
            );
        }
    }
}

#[test]
fn an_object_touching_the_border_stays_attached_to_it() {
    let focus = 4.0;
    let scene = Scene::wall(4.0).rect(0..12, 10..30, RED, 1.0);
    for border in [Border::Extend, Border::Crop] {
        let config = LdiConfig {
            border,
            ..LdiConfig::default()
        };
        let ldi = scene.build(&config, 0.15);
        for tx in [-0.15, 0.15] {
            let view = render(&ldi, &scene, tx, focus);
            assert!(
                view.hole_fraction.iter().all(|&h| h == 0.0),
                "{border:?} tx={tx}: holes"
            );
            if border == Border::Crop {
                continue;
            }
            let right = 12.0 + shift(tx, 1.0, focus);
            // Moving right or left, the object still starts at the frame's left edge.
            assert_golden(&view.image, 12..28, &[right], |x| {
                if x < right {
                    Label::Red
                } else {
                    Label::Wall
                }
            });
            assert_golden(&view.image, 32..H, &[], |_| Label::Wall);
        }
    }
}

#[test]
fn nested_occluders_uncover_the_surface_directly_behind() {
    let focus = 4.0;
    // Wall at 4, a green board at 2, a red block at 1 inside the board.
    let scene = Scene::wall(4.0)
        .rect(14..50, 6..42, GREEN, 2.0)
        .rect(28..36, 18..30, RED, 1.0);
    let ldi = scene.build(&LdiConfig::default(), 0.2);
    for tx in [-0.2, -0.1, 0.1, 0.2] {
        let view = render(&ldi, &scene, tx, focus);
        assert!(
            view.hole_fraction.iter().all(|&h| h == 0.0),
            "tx={tx}: holes"
        );
        let (sg, sr) = (shift(tx, 2.0, focus), shift(tx, 1.0, focus));
        let (g0, g1, r0, r1) = (14.0 + sg, 50.0 + sg, 28.0 + sr, 36.0 + sr);
        assert!(
            (sr - sg).abs() > 2.5,
            "the test needs a disocclusion wider than its margins"
        );
        assert_golden(&view.image, 20..28, &[g0, g1, r0, r1], |x| {
            if (r0..r1).contains(&x) {
                Label::Red
            } else if (g0..g1).contains(&x) {
                Label::Green
            } else {
                Label::Wall
            }
        });
        assert_golden(&view.image, 10..14, &[g0, g1], |x| {
            if (g0..g1).contains(&x) {
                Label::Green
            } else {
                Label::Wall
            }
        });
    }
}
