//! The practical-identifiability flags of `cellcal identify` (`--noise-mm`, `--max-sigma-mm`,
//! `--max-sigma-mrad`).

use anyhow::anyhow;
use cellcal::identify::identifiability;
use cellcal::identify::PracticalBounds;
use clap::Args;

/// Practical identifiability: a parameter whose predicted σ (a-priori noise × √diag (JᵀJ)⁻¹ on
/// these poses) would exceed its bound is held at nominal and listed with its reason.
#[derive(Args, Clone, Copy)]
pub struct PracticalArgs {
    /// A-priori σ of one measured coordinate (mm) for the predicted parameter σ [default: 0.015,
    /// an AT960 at ~2.5 m]. Not with --tracker-weights, whose model gives it (σ at 1 m).
    #[arg(long, allow_negative_numbers = true)]
    noise_mm: Option<f64>,
    /// Largest predicted σ (noise × √diag (JᵀJ)⁻¹ on these poses) of an identified length (mm);
    /// a parameter over its bound is held at nominal and listed with the reason.
    #[arg(long, allow_negative_numbers = true, default_value_t = identifiability::DEFAULT_MAX_SIGMA_MM)]
    max_sigma_mm: f64,
    /// Largest predicted σ of an identified angle (mrad).
    #[arg(long, allow_negative_numbers = true, default_value_t = identifiability::DEFAULT_MAX_SIGMA_RAD * 1e3)]
    max_sigma_mrad: f64,
}

impl PracticalArgs {
    /// The bounds, or why they are unusable.
    pub fn bounds(self, tracker_weights: bool) -> anyhow::Result<PracticalBounds> {
        if tracker_weights && self.noise_mm.is_some() {
            anyhow::bail!(
                "--noise-mm conflicts with --tracker-weights (the tracker model gives the noise)"
            );
        }
        let b = PracticalBounds {
            noise_mm: self.noise_mm.unwrap_or(identifiability::DEFAULT_NOISE_MM),
            max_sigma_mm: self.max_sigma_mm,
            max_sigma_rad: self.max_sigma_mrad / 1e3,
        };
        b.check()
            .map_err(|e| anyhow!("--noise-mm/--max-sigma-mm/--max-sigma-mrad: {e}"))?;
        Ok(b)
    }
}
