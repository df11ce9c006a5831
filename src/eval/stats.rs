//! Image statistics shared by the evaluations.

/// PSNR in dB of a mean squared error on a 0-1 scale; infinite for identical images.
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_is_20_db_at_a_tenth_rms_and_infinite_at_zero() {
        assert!((psnr_from_mse(0.01) - 20.0).abs() < 1e-12);
        assert_eq!(psnr_from_mse(0.0), f64::INFINITY);
    }
}
