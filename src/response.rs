//! The camera's inverse response `g = f⁻¹`: brightness `B ∈ [0, 1]` to relative exposure.
//!
//! [`InverseResponse`] is what every later stage consumes (merge, cache, daemon): per
//! channel, `g` sampled at `n` evenly spaced brightness values `B_i = i/(n−1)`, normalised
//! `g(0) = 0`, `g(1) = 1`, non-decreasing, evaluated between samples by linear
//! interpolation. How `g` was obtained (a fit, a cache, a default) is recorded beside it.

/// Why an inverse response is not acceptable.
#[derive(Debug, thiserror::Error)]
pub enum ResponseError {
    /// Not 1 or 3 channels, or fewer than two samples.
    #[error("inverse response needs 1 or 3 channels of at least 2 samples, got {0}")]
    Shape(String),
    /// A sample is NaN/∞, outside [0, 1], decreasing, or the ends are not 0 and 1.
    #[error("inverse response channel {channel}: {reason}")]
    Invalid {
        /// Channel index.
        channel: usize,
        /// What is wrong.
        reason: String,
    },
}

/// Per-channel sampled inverse response (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct InverseResponse {
    channels: Vec<Vec<f64>>,
}

impl InverseResponse {
    /// Validates per-channel samples `g(i/(n−1))`: finite, non-decreasing, `g(0)=0`, `g(1)=1`.
    pub fn from_samples(channels: Vec<Vec<f64>>) -> Result<InverseResponse, ResponseError> {
        if !(channels.len() == 1 || channels.len() == 3) || channels.iter().any(|c| c.len() < 2) {
            return Err(ResponseError::Shape(format!(
                "{} channels of lengths {:?}",
                channels.len(),
                channels.iter().map(Vec::len).collect::<Vec<_>>()
            )));
        }
        for (channel, g) in channels.iter().enumerate() {
            let bad = |reason: String| ResponseError::Invalid { channel, reason };
            if let Some(i) = g.iter().position(|v| !v.is_finite()) {
                return Err(bad(format!("sample {i} is not finite")));
            }
            if g[0] != 0.0 || g[g.len() - 1] != 1.0 {
                return Err(bad(format!(
                    "ends are {} and {}, must be 0 and 1",
                    g[0],
                    g[g.len() - 1]
                )));
            }
            if let Some(i) = g.windows(2).position(|w| w[1] < w[0]) {
                return Err(bad(format!("decreases between samples {i} and {}", i + 1)));
            }
        }
        Ok(InverseResponse { channels })
    }

    /// The inverse of the sRGB transfer function (IEC 61966-2-1), the usual response of a
    /// camera JPEG when nothing better is known:
    /// `g(B) = B/12.92` for `B ≤ 0.04045`, else `((B+0.055)/1.055)^2.4`.
    pub fn srgb(channels: usize, samples: usize) -> InverseResponse {
        let g = (0..samples)
            .map(|i| {
                let b = i as f64 / (samples - 1) as f64;
                if b <= 0.04045 {
                    b / 12.92
                } else {
                    ((b + 0.055) / 1.055).powf(2.4)
                }
            })
            .collect::<Vec<_>>();
        InverseResponse {
            channels: vec![g; channels],
        }
    }

    /// Number of channels (1 or 3).
    pub fn channels(&self) -> usize {
        self.channels.len()
    }

    /// The samples of channel `c`, `g(i/(n−1))`.
    pub fn samples(&self, c: usize) -> &[f64] {
        &self.channels[c]
    }

    /// `g(B)` for channel `c`, linear between samples; `B` is clamped to `[0, 1]`
    /// (NaN reads as 0).
    pub fn eval(&self, c: usize, b: f64) -> f64 {
        let g = &self.channels[c];
        let b = if b.is_nan() { 0.0 } else { b.clamp(0.0, 1.0) };
        let x = b * (g.len() - 1) as f64;
        let i = (x.floor() as usize).min(g.len() - 2);
        let f = x - i as f64;
        g[i] + (g[i + 1] - g[i]) * f
    }

    /// Lookup table for integer codes: `g(k/(levels−1))` for `k = 0..levels`.
    pub fn table(&self, c: usize, levels: usize) -> Vec<f32> {
        (0..levels)
            .map(|k| self.eval(c, k as f64 / (levels - 1) as f64) as f32)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_is_valid_and_interpolates() {
        let g = InverseResponse::srgb(3, 1024);
        let again = InverseResponse::from_samples((0..3).map(|c| g.samples(c).to_vec()).collect());
        assert!(again.is_ok());
        assert_eq!(g.eval(0, 0.0), 0.0);
        assert_eq!(g.eval(2, 1.0), 1.0);
        let mid = g.eval(1, 0.5);
        assert!((mid - 0.214).abs() < 1e-3, "{mid}");
        assert_eq!(g.eval(0, f64::NAN), 0.0);
    }

    #[test]
    fn rejects_decreasing_and_unnormalised() {
        assert!(InverseResponse::from_samples(vec![vec![0.0, 0.6, 0.5, 1.0]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, 0.5, 0.9]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, f64::NAN, 1.0]]).is_err());
        assert!(InverseResponse::from_samples(vec![vec![0.0, 1.0]; 2]).is_err());
    }
}
