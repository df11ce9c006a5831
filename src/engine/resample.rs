//! Planar f32 image helpers for the network's inputs and outputs: replicate padding,
//! area downsampling and bilinear upsampling (half-pixel centres, as PyTorch's
//! `align_corners=False`).

/// Pads each `w`×`h` plane of `src` to `pw`×`ph` by repeating the last row and column,
/// as the training toolchain's evaluation pads (bottom and right only).
pub fn pad_replicate(src: &[f32], w: usize, h: usize, pw: usize, ph: usize) -> Vec<f32> {
    let planes = src.len() / (w * h);
    let mut out = Vec::with_capacity(planes * pw * ph);
    for plane in src.chunks_exact(w * h) {
        for y in 0..ph {
            let row = &plane[y.min(h - 1) * w..][..w];
            out.extend_from_slice(row);
            out.extend(std::iter::repeat_n(row[w - 1], pw - w));
        }
    }
    out
}

/// The top-left `w`×`h` of each `pw`×`ph` plane of `src`.
pub fn crop(src: &[f32], pw: usize, ph: usize, w: usize, h: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(src.len() / (pw * ph) * w * h);
    for plane in src.chunks_exact(pw * ph) {
        for y in 0..h {
            out.extend_from_slice(&plane[y * pw..][..w]);
        }
    }
    out
}

/// Resamples each plane from `w`×`h` to `nw`×`nh`: area averaging where a side shrinks,
/// bilinear interpolation where it grows.
pub fn resize(src: &[f32], w: usize, h: usize, nw: usize, nh: usize) -> Vec<f32> {
    let xs = weights(w, nw);
    let ys = weights(h, nh);
    let mut out = Vec::with_capacity(src.len() / (w * h) * nw * nh);
    let mut rows = vec![0.0f32; nw * h];
    for plane in src.chunks_exact(w * h) {
        for (y, row) in rows.chunks_exact_mut(nw).enumerate() {
            let line = &plane[y * w..][..w];
            for (o, taps) in row.iter_mut().zip(&xs) {
                *o = taps.iter().map(|&(i, k)| line[i] * k).sum();
            }
        }
        for taps in &ys {
            let start = out.len();
            out.resize(start + nw, 0.0);
            for &(y, k) in taps {
                for (o, &v) in out[start..].iter_mut().zip(&rows[y * nw..][..nw]) {
                    *o += v * k;
                }
            }
        }
    }
    out
}

/// For each output index, the input indices and weights that make it (weights sum to 1).
fn weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    if m >= n {
        bilinear_weights(n, m)
    } else {
        area_weights(n, m)
    }
}

fn bilinear_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = n as f64 / m as f64;
    (0..m)
        .map(|j| {
            let x = ((j as f64 + 0.5) * scale - 0.5).clamp(0.0, (n - 1) as f64);
            let i = x.floor() as usize;
            let f = (x - i as f64) as f32;
            if i + 1 < n && f > 0.0 {
                vec![(i, 1.0 - f), (i + 1, f)]
            } else {
                vec![(i, 1.0)]
            }
        })
        .collect()
}

fn area_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = n as f64 / m as f64;
    (0..m)
        .map(|j| {
            let (lo, hi) = (j as f64 * scale, (j + 1) as f64 * scale);
            let first = lo.floor() as usize;
            let last = (hi.ceil() as usize).min(n);
            (first..last)
                .map(|i| {
                    let overlap = hi.min(i as f64 + 1.0) - lo.max(i as f64);
                    (i, (overlap / scale) as f32)
                })
                .filter(|&(_, k)| k > 0.0)
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padding_repeats_the_edge_and_crop_undoes_it() {
        let src = [1.0, 2.0, 3.0, 4.0];
        let padded = pad_replicate(&src, 2, 2, 3, 3);
        assert_eq!(padded, [1.0, 2.0, 2.0, 3.0, 4.0, 4.0, 3.0, 4.0, 4.0]);
        assert_eq!(crop(&padded, 3, 3, 2, 2), src);
    }

    #[test]
    fn area_downsampling_averages_blocks() {
        let src = [1.0, 3.0, 5.0, 7.0, 1.0, 3.0, 5.0, 7.0];
        assert_eq!(resize(&src, 4, 2, 2, 1), [2.0, 6.0]);
    }

    #[test]
    fn resizing_keeps_constants_and_same_size_is_identity() {
        let src = vec![0.5f32; 7 * 5];
        for (nw, nh) in [(3, 2), (14, 10), (11, 3)] {
            let out = resize(&src, 7, 5, nw, nh);
            assert_eq!(out.len(), nw * nh);
            assert!(out.iter().all(|v| (v - 0.5).abs() < 1e-6), "{nw}x{nh}");
        }
        let ramp: Vec<f32> = (0..12).map(|i| i as f32).collect();
        assert_eq!(resize(&ramp, 4, 3, 4, 3), ramp);
    }

    #[test]
    fn bilinear_upsampling_matches_half_pixel_centres() {
        // PyTorch: interpolate([0, 1], scale 2, bilinear, align_corners=False).
        let out = resize(&[0.0, 1.0], 2, 1, 4, 1);
        assert_eq!(out, [0.0, 0.25, 0.75, 1.0]);
    }
}
