//! Unit tests of `device::capture::live`, beside it so that the module file holds the code only.

use super::*;

#[test]
fn cover_resize_crops_to_the_target_aspect() {
    // Left half red, right half blue, 8x2; covering 2x2 keeps the centre 2x2 columns
    // 3..5, one red and one blue.
    let image = RgbImage::from_fn(8, 2, |x, _| {
        if x < 4 {
            image::Rgb([255, 0, 0])
        } else {
            image::Rgb([0, 0, 255])
        }
    });
    let out = cover_resize(&image, 2, 2);
    assert_eq!(out.get_pixel(0, 0).0, [255, 0, 0]);
    assert_eq!(out.get_pixel(1, 1).0, [0, 0, 255]);
    assert_eq!(cover_resize(&image, 4, 1).dimensions(), (4, 1));
}
