//! Unit tests of `eval::reshade`, beside it so that the module file holds the code only.

use super::*;

#[test]
fn conv_count_matches_the_toolchain_for_the_tiny_net() {
    // The encoder of widths 4,8,8,16,16,16 (one conv per block) at 64x96, by hand.
    let (enc, _) = conv_gflop(&[4, 8, 8, 16, 16, 16], &[1; 6], 3, 64, 96).unwrap();
    let px = |l: u32| (64 >> l) as f64 * (96 >> l) as f64;
    let e = 2.0
        * 9.0
        * (px(0) * 14.0 * 4.0
            + px(1) * 4.0 * 8.0
            + px(2) * 8.0 * 8.0
            + px(3) * 8.0 * 16.0
            + px(4) * 16.0 * 16.0
            + px(5) * 16.0 * 16.0);
    assert!((enc * 1e9 - e).abs() < 1.0);
    // reshader_train.model.conv_flops for this net at 384x640: encoder 0.3151872,
    // decoder 0.5142528 GFLOP (residual head), 0.62042112 (camera-linear head).
    let (enc, dec) = conv_gflop(&[4, 8, 8, 16, 16, 16], &[1; 6], 3, 384, 640).unwrap();
    assert!((enc - 0.315_187_2).abs() < 1e-9, "{enc}");
    assert!((dec - 0.514_252_8).abs() < 1e-9, "{dec}");
    let (_, dec) = conv_gflop(&[4, 8, 8, 16, 16, 16], &[1; 6], 9, 384, 640).unwrap();
    assert!((dec - 0.620_421_12).abs() < 1e-9, "{dec}");
    assert!(conv_gflop(&[1, 2], &[1, 1], 3, 32, 32).is_none());
}

#[test]
fn ratios_fill_in_per_precision() {
    let row = "| tract | fp32 | 1 | 2 | 3 | {ort:fp32:30} |";
    assert_eq!(
        fill_ratio(row, &[(Precision::Fp32, 10.0)]),
        "| tract | fp32 | 1 | 2 | 3 | 3.00× |"
    );
    assert_eq!(fill_ratio(row, &[]), "| tract | fp32 | 1 | 2 | 3 | – |");
}

#[test]
fn psnr_is_infinite_for_equal_images_and_finite_otherwise() {
    let (a, _) = test_scene(8, 4);
    assert!(psnr(&a, &a).is_infinite());
    let mut b = a.clone();
    b.put(0, 0, [0.0, 0.0, 0.0]);
    assert!(psnr(&a, &b).is_finite());
}
