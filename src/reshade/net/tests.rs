//! Unit tests of `reshade::net`, beside it so that the module file holds the code only.

use super::models::partner_name;
use super::*;

#[test]
fn disparity_follows_the_contract() {
    assert_eq!(disparity(0.25), 1.0);
    assert_eq!(disparity(0.1), 1.0);
    assert_eq!(disparity(1.0), 0.25);
    assert_eq!(disparity(f32::INFINITY), 0.0);
    assert_eq!(disparity(0.0), 0.0);
    assert_eq!(disparity(f32::NAN), 0.0);
}

#[test]
fn sizes_round_up_to_the_multiple() {
    assert_eq!(round_up(640, 32), 640);
    assert_eq!(round_up(641, 32), 672);
    assert_eq!(round_up(1, 32), 32);
}

#[test]
fn partner_names_swap_the_half() {
    assert_eq!(
        partner_name("reshade-lite-int8-encoder", Task::ReshadeEncoder),
        "reshade-lite-int8-decoder"
    );
    assert_eq!(partner_name("x-decoder", Task::ReshadeDecoder), "x-encoder");
}

#[test]
fn options_are_checked() {
    let bad = [
        NetOptions {
            scale: 0.0,
            ..Default::default()
        },
        NetOptions {
            scale: 1.5,
            ..Default::default()
        },
        NetOptions {
            batch: 0,
            ..Default::default()
        },
        NetOptions {
            key_views: Some(1),
            ..Default::default()
        },
        NetOptions {
            max_side: Some(0),
            ..Default::default()
        },
    ];
    for o in bad {
        assert!(o.check().is_err(), "{o:?}");
    }
    assert!(NetOptions::default().check().is_ok());
}

#[test]
fn the_working_size_fits_the_longest_side_and_the_scale() {
    let default = NetOptions::default();
    // A 12 MP photo fitted to the Portrait's views, and the shipped example.
    assert_eq!(default.working_size(747, 560), (256, 192));
    assert_eq!(default.working_size(288, 384), (192, 256));
    assert_eq!(default.working_size(200, 120), (200, 120));
    let both = NetOptions {
        scale: 0.25,
        ..Default::default()
    };
    assert_eq!(both.working_size(747, 560), (187, 140));
    let tenth = NetOptions {
        scale: 0.1,
        ..Default::default()
    };
    assert_eq!(tenth.working_size(747, 560), (75, 56));
    let unlimited = NetOptions {
        max_side: None,
        ..Default::default()
    };
    assert_eq!(unlimited.working_size(747, 560), (747, 560));
    assert_eq!(default.working_size(4000, 1), (256, 1));
}
