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
    ];
    for o in bad {
        assert!(o.check().is_err(), "{o:?}");
    }
    assert!(NetOptions::default().check().is_ok());
}
