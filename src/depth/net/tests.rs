//! Unit tests of `depth::net`, beside it so that the module file holds the code only.

use super::resize::area_taps;
use super::*;

#[test]
fn tiefenrausch_policy_gives_the_reference_sizes() {
    let p = SizePolicy::LongestSide {
        size: 384,
        multiple: 32,
    };
    assert_eq!(p.network_size(3024, 4032), Some((288, 384)));
    assert_eq!(p.network_size(768, 1024), Some((288, 384)));
    assert_eq!(p.network_size(4000, 3000), Some((384, 288)));
    // 16:9 landscape: 384 x 216 -> 384 x 192.
    assert_eq!(p.network_size(1920, 1080), Some((384, 192)));
    assert_eq!(p.network_size(4000, 10), None);
}

#[test]
fn multiple_policy_rounds_to_nearest_and_caps_the_long_side() {
    let p = SizePolicy::Multiple {
        max_side: Some(518),
        multiple: 14,
    };
    assert_eq!(p.network_size(1036, 777), Some((518, 392)));
    let p = SizePolicy::Multiple {
        max_side: None,
        multiple: 32,
    };
    assert_eq!(p.network_size(100, 40), Some((96, 32)));
}

#[test]
fn area_resize_averages_whole_blocks_exactly() {
    let img = RgbImage::from_fn(4, 2, |x, _| image::Rgb([x as u8 * 10, 1, 2]));
    let out = area_resize(&img, 2, 1);
    // (0+10+0+10+2)>>2 = 5 (round half up on the fast path), (20+30+20+30+2)>>2 = 25.
    assert_eq!(out.get_pixel(0, 0).0, [5, 1, 2]);
    assert_eq!(out.get_pixel(1, 0).0, [25, 1, 2]);
}

#[test]
fn area_taps_cover_each_source_pixel_once() {
    for (src, dst) in [(1024, 384), (768, 288), (10, 3), (7, 5)] {
        let taps = area_taps(src, dst);
        let mut cover = vec![0.0f64; src];
        for row in &taps {
            let sum: f64 = row.iter().map(|&(_, w)| f64::from(w)).sum();
            assert!(
                (sum - 1.0).abs() < 1e-3,
                "{src}->{dst}: weights sum to {sum}"
            );
            for &(s, w) in row {
                cover[s] += f64::from(w) * src as f64 / dst as f64;
            }
        }
        assert!(cover.iter().all(|c| (c - 1.0).abs() < 2e-3), "{src}->{dst}");
    }
}

#[test]
fn scene_scale_puts_percentiles_at_near_and_far() {
    let disparity: Vec<f32> = (0..101).map(|i| i as f32).collect();
    let scale = SceneScale {
        near: 2.0,
        budget: 6.0,
    };
    let (map, [lo, hi]) = scale.depth_from_disparity(101, 1, &disparity);
    assert_eq!((lo, hi), (2.0, 98.0));
    assert!((map.at(98, 0) - 2.0).abs() < 1e-4);
    assert!((map.at(2, 0) - 8.0).abs() < 1e-3);
    assert!(map.data().windows(2).all(|w| w[1] <= w[0]));
}
