//! Resizing the photo to the network's input the way the model was trained on it:
//! OpenCV's `INTER_AREA` reproduced bit for bit.

use image::RgbImage;

/// Area-averages a uint8 RGB image down to `w`×`h`, rounding back to uint8 the way
/// OpenCV's `INTER_AREA` does: the network is sensitive to one-level input changes, so
/// the reference numbers are only reproduced with the same float32 sums in the same order.
pub fn area_resize(img: &RgbImage, w: usize, h: usize) -> RgbImage {
    let (sw, sh) = (img.width() as usize, img.height() as usize);
    assert!(
        w > 0 && h > 0 && w <= sw && h <= sh,
        "area resize only shrinks"
    );
    let data = if sw % w == 0 && sh % h == 0 {
        block_mean(img.as_raw(), sw, sw / w, sh / h, w, h)
    } else {
        separable_area(img.as_raw(), sw, sh, w, h)
    };
    RgbImage::from_raw(w as u32, h as u32, data).expect("buffer matches size")
}

/// Whole-number shrink factors: exact integer block sums, rounded as OpenCV's fast path.
fn block_mean(src: &[u8], sw: usize, fx: usize, fy: usize, w: usize, h: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(w * h * 3);
    let inv = 1.0f32 / (fx * fy) as f32;
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut sum = 0u32;
                for yy in y * fy..(y + 1) * fy {
                    for xx in x * fx..(x + 1) * fx {
                        sum += u32::from(src[(yy * sw + xx) * 3 + c]);
                    }
                }
                out.push(if fx * fy == 4 {
                    ((sum + 2) >> 2) as u8
                } else {
                    (sum as f32 * inv).round_ties_even().clamp(0.0, 255.0) as u8
                });
            }
        }
    }
    out
}

/// Source indices and float32 weights of the source interval each output pixel covers;
/// partial overlaps under 1e-3 of a pixel are dropped, as OpenCV does.
pub(super) fn area_taps(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|d| {
            let (lo, hi) = (d as f64 * scale, (d + 1) as f64 * scale);
            let (first, last) = (lo.ceil() as usize, hi.floor() as usize);
            let mut taps = Vec::new();
            if first as f64 - lo > 1e-3 {
                taps.push((first - 1, ((first as f64 - lo) / scale) as f32));
            }
            taps.extend((first..last).map(|s| (s, (1.0 / scale) as f32)));
            if hi - last as f64 > 1e-3 && last < src {
                taps.push((last, ((hi - last as f64) / scale) as f32));
            }
            taps
        })
        .collect()
}

/// General shrink factors: each source row is shrunk horizontally, then the rows are
/// combined, both in float32 with the taps summed in source order.
fn separable_area(src: &[u8], sw: usize, sh: usize, w: usize, h: usize) -> Vec<u8> {
    let xt = area_taps(sw, w);
    let yt = area_taps(sh, h);
    let mut rows = vec![0.0f32; sh * w * 3];
    for y in 0..sh {
        for (x, taps) in xt.iter().enumerate() {
            for c in 0..3 {
                let mut acc = 0.0f32;
                for &(s, wt) in taps {
                    acc += f32::from(src[(y * sw + s) * 3 + c]) * wt;
                }
                rows[(y * w + x) * 3 + c] = acc;
            }
        }
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for taps in &yt {
        for i in 0..w * 3 {
            let mut acc = 0.0f32;
            for &(s, wt) in taps {
                acc += wt * rows[s * w * 3 + i];
            }
            out.push(acc.round_ties_even().clamp(0.0, 255.0) as u8);
        }
    }
    out
}
