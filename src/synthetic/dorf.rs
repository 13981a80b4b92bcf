//! Response curves read from a file: the DoRF database's `dorf-even.csv` layout.

use std::path::Path;

use super::{ResponseCurve, SyntheticError};

/// Weight of the identity mixed into a sampled curve with flat steps to make it strictly
/// increasing: `f ← (f + ε·X)/(1 + ε)` moves no value by more than `ε` (1/8 of a 16-bit code).
const FLAT_STEP_LIFT: f64 = 1e-6;

/// Reads response curves from a CSV file such as the Database of Response Functions
/// (Grossberg & Nayar): lines starting with `#` are comments; every other non-empty line is
/// `index, B_0, B_1, …, B_{n−1}` with `B_k = f(k/(n−1))`. Curves are named `dorf-<index>`.
///
/// Real curves may contain flat steps (equal neighbouring samples, 3 of the 101 in
/// `dorf-even.csv`); they are made strictly increasing by mixing in a trace of the identity,
/// `B ← (B + ε·X)/(1 + ε)` with `ε = 10⁻⁶`, which moves no sample by more than 10⁻⁶
/// (below 1/8 of a 16-bit code). A decreasing curve or ends other than 0 and 1 are errors.
pub fn dorf_curves(path: &Path) -> Result<Vec<(String, ResponseCurve)>, SyntheticError> {
    let text = std::fs::read_to_string(path).map_err(|source| SyntheticError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let mut curves = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parse_error = |reason: String| SyntheticError::Parse {
            path: path.to_path_buf(),
            line: number + 1,
            reason,
        };
        let mut fields = line.split(',').map(str::trim);
        let index = fields.next().unwrap_or_default();
        let index: u32 = index
            .parse()
            .map_err(|_| parse_error(format!("curve index {index:?} is not a whole number")))?;
        let mut samples = fields
            .enumerate()
            .map(|(k, v)| {
                v.parse::<f64>()
                    .map_err(|_| parse_error(format!("sample {k} {v:?} is not a number")))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        if samples.windows(2).any(|w| w[1] == w[0]) {
            let last = (samples.len().max(2) - 1) as f64;
            for (k, s) in samples.iter_mut().enumerate() {
                *s = (*s + FLAT_STEP_LIFT * k as f64 / last) / (1.0 + FLAT_STEP_LIFT);
            }
            if let Some(end) = samples.last_mut() {
                // (1 + ε)/(1 + ε) may round; the end is 1 by construction.
                if (*end - 1.0).abs() < 1e-12 {
                    *end = 1.0;
                }
            }
        }
        let curve = ResponseCurve::Sampled(samples);
        curve.broken().map_err(|source| SyntheticError::FileCurve {
            path: path.to_path_buf(),
            line: number + 1,
            index,
            source,
        })?;
        curves.push((format!("dorf-{index}"), curve));
    }
    if curves.is_empty() {
        return Err(SyntheticError::Parse {
            path: path.to_path_buf(),
            line: 0,
            reason: "no curves in file".to_string(),
        });
    }
    Ok(curves)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dorf_file_is_parsed_and_flat_steps_lifted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curves.csv");
        std::fs::write(&path, "# comment\n\n7, 0, 0.5, 1\n9,0,0.2,0.2,1\n").unwrap();
        let curves = dorf_curves(&path).unwrap();
        assert_eq!(curves.len(), 2);
        assert_eq!(curves[0].0, "dorf-7");
        assert_eq!(curves[0].1, ResponseCurve::Sampled(vec![0.0, 0.5, 1.0]));
        let ResponseCurve::Sampled(lifted) = &curves[1].1 else {
            panic!("sampled curve expected")
        };
        assert_eq!((lifted[0], lifted[3]), (0.0, 1.0));
        assert!(lifted[2] > lifted[1] && (lifted[2] - 0.2).abs() < 1e-6);
    }

    #[test]
    fn dorf_errors_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.csv");
        std::fs::write(&path, "# c\n1, 0, 0.7, 0.4, 1\n").unwrap();
        let message = dorf_curves(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.csv:2") && message.contains("strictly"),
            "{message}"
        );
        std::fs::write(&path, "1, 0, x, 1\n").unwrap();
        let message = dorf_curves(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.csv:1") && message.contains("\"x\""),
            "{message}"
        );
        std::fs::write(&path, "# only comments\n").unwrap();
        assert!(dorf_curves(&path).is_err());
        let missing = dir.path().join("missing.csv");
        let message = dorf_curves(&missing).unwrap_err().to_string();
        assert!(message.contains("missing.csv"), "{message}");
    }
}
