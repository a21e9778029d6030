//! The laser tracker's uncertainty model, σ = (a + b·range)/k per axis: what identification
//! weighs points by (`IdentifyOptions::point_weights`) and what the simulator adds as noise
//! (`simulate`, `sim`). It lives here, below both, so that identification needs nothing of the
//! simulator.

use nalgebra::Vector3;

/// Laser-tracker noise model: per-axis σ = (a + b·range)/k.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerNoise {
    /// Tracker position in the measurement frame (mm).
    pub position_mm: Vector3<f64>,
    /// Constant term of the MPE (µm).
    pub a_um: f64,
    /// Range-proportional term of the MPE (µm per m).
    pub b_um_per_m: f64,
    /// Coverage factor: σ = MPE/k.
    pub k: f64,
}

impl TrackerNoise {
    /// AT960 noise with the tracker at `position_mm`.
    pub fn at960(position_mm: Vector3<f64>) -> TrackerNoise {
        TrackerNoise {
            position_mm,
            a_um: 15.0,
            b_um_per_m: 6.0,
            k: 2.0,
        }
    }

    /// Per-axis σ (mm) of a point at `p` (measurement frame).
    pub fn sigma_mm(&self, p: &Vector3<f64>) -> f64 {
        let range_m = (p - self.position_mm).norm() / 1000.0;
        (self.a_um + self.b_um_per_m * range_m) / 1000.0 / self.k
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at960_sigma_grows_with_range() {
        let t = TrackerNoise::at960(Vector3::zeros());
        // (15 µm + 6 µm/m · 2 m) / 2
        assert!((t.sigma_mm(&Vector3::new(2000.0, 0.0, 0.0)) - 0.0135).abs() < 1e-15);
        assert!((t.sigma_mm(&Vector3::zeros()) - 0.0075).abs() < 1e-15);
    }

    /// Identification sits below the simulator: no file of `identify/` names `simulate`
    /// (the identify ↔ simulate cycle of issue 18).
    #[test]
    fn identify_does_not_use_the_simulator() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/identify");
        let needle = ["simulate", "::"].concat();
        let mut files = vec![dir.with_extension("rs")];
        for e in std::fs::read_dir(&dir).expect("src/identify") {
            files.push(e.expect("entry").path());
        }
        for f in files.into_iter().filter(|f| f.exists()) {
            let text = std::fs::read_to_string(&f).expect("readable");
            let uses: Vec<&str> = text
                .lines()
                .filter(|l| !l.trim_start().starts_with("//") && l.contains(&needle))
                .collect();
            assert!(uses.is_empty(), "{}: {uses:?}", f.display());
        }
    }
}
