//! Non-geometric joint terms (§10): small corrections of each joint's angle that repeat with
//! the pose — compliance under the gravity torque and the first two harmonics of the joint
//! angle. The link angle is `q_j + Δθ_j(q)` with
//! `Δθ_j = c_j·τ_j(q) + s1_j·sin q_j + c1_j·cos q_j + s2_j·sin 2q_j + c2_j·cos 2q_j`.

/// One coefficient of a joint's correction `Δθ_j(q)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TermKind {
    /// `c_j` of `c_j·τ_j(q)`, τ the gravity torque about the joint (rad/(N·m)).
    Compliance,
    /// Coefficient of `sin q_j` (rad).
    SinQ,
    /// Coefficient of `cos q_j` (rad).
    CosQ,
    /// Coefficient of `sin 2q_j` (rad).
    Sin2Q,
    /// Coefficient of `cos 2q_j` (rad).
    Cos2Q,
}

impl TermKind {
    /// Every kind, in the order of [`JointTerms`]' fields.
    pub const ALL: [TermKind; 5] = [
        TermKind::Compliance,
        TermKind::SinQ,
        TermKind::CosQ,
        TermKind::Sin2Q,
        TermKind::Cos2Q,
    ];

    /// Contract name: `compliance`, `sin_q`, `cos_q`, `sin_2q`, `cos_2q`.
    pub fn name(self) -> &'static str {
        match self {
            TermKind::Compliance => "compliance",
            TermKind::SinQ => "sin_q",
            TermKind::CosQ => "cos_q",
            TermKind::Sin2Q => "sin_2q",
            TermKind::Cos2Q => "cos_2q",
        }
    }

    /// Unit of the coefficient: `rad/(N·m)` for compliance, `rad` for a harmonic.
    pub fn unit(self) -> &'static str {
        match self {
            TermKind::Compliance => "rad/(N·m)",
            _ => "rad",
        }
    }

    /// The family the kind belongs to.
    pub fn family(self) -> TermFamily {
        match self {
            TermKind::Compliance => TermFamily::Compliance,
            _ => TermFamily::Harmonics,
        }
    }

    /// What multiplies the coefficient at commanded joint value `q` (rad) with gravity torque
    /// `tau` (N·m) about the joint.
    pub fn basis(self, q: f64, tau: f64) -> f64 {
        self.basis_trig(q.sin_cos(), tau)
    }

    /// [`TermKind::basis`] given `(sin q, cos q)`: the double angle by identities, so a pose's
    /// table of sines serves every term without another sine.
    pub fn basis_trig(self, (s, c): (f64, f64), tau: f64) -> f64 {
        match self {
            TermKind::Compliance => tau,
            TermKind::SinQ => s,
            TermKind::CosQ => c,
            TermKind::Sin2Q => 2.0 * s * c,
            TermKind::Cos2Q => (c - s) * (c + s),
        }
    }
}

/// A set of terms chosen together: `compliance` or `harmonics` in `--nongeometric`, in
/// `[campaign] nongeometric` and in JSON.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum TermFamily {
    /// One compliance per joint that carries a gravity lever.
    Compliance,
    /// Four harmonic coefficients per joint.
    Harmonics,
}

impl TermFamily {
    /// Both families.
    pub const ALL: [TermFamily; 2] = [TermFamily::Compliance, TermFamily::Harmonics];

    /// Contract name: `compliance`, `harmonics`.
    pub fn name(self) -> &'static str {
        match self {
            TermFamily::Compliance => "compliance",
            TermFamily::Harmonics => "harmonics",
        }
    }

    /// The kinds of this family.
    pub fn kinds(self) -> &'static [TermKind] {
        match self {
            TermFamily::Compliance => &TermKind::ALL[..1],
            TermFamily::Harmonics => &TermKind::ALL[1..],
        }
    }

    /// Parse a comma-separated list (`compliance,harmonics`), each name once.
    pub fn parse_list(s: &str) -> Result<Vec<TermFamily>, UnknownFamily> {
        let mut out = Vec::new();
        for part in s.split(',').map(str::trim) {
            let f: TermFamily = part.parse()?;
            if !out.contains(&f) {
                out.push(f);
            }
        }
        out.sort();
        Ok(out)
    }
}

impl std::str::FromStr for TermFamily {
    type Err = UnknownFamily;
    fn from_str(s: &str) -> Result<TermFamily, UnknownFamily> {
        TermFamily::ALL
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| UnknownFamily(s.to_owned()))
    }
}

impl std::fmt::Display for TermFamily {
    /// The contract name.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not a family of non-geometric terms.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}` is not one of compliance, harmonics")]
pub struct UnknownFamily(pub String);

/// The non-geometric coefficients of one joint (all zero: none).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointTerms {
    /// `c_j` (rad/(N·m)).
    pub compliance: f64,
    /// Coefficients of `sin q`, `cos q`, `sin 2q`, `cos 2q` (rad).
    pub harmonics: [f64; 4],
}

impl JointTerms {
    /// The coefficient of `kind`.
    pub fn get(&self, kind: TermKind) -> f64 {
        match kind {
            TermKind::Compliance => self.compliance,
            k => self.harmonics[k as usize - 1],
        }
    }

    /// The coefficient of `kind`, to change.
    pub fn get_mut(&mut self, kind: TermKind) -> &mut f64 {
        match kind {
            TermKind::Compliance => &mut self.compliance,
            k => &mut self.harmonics[k as usize - 1],
        }
    }

    /// Whether every coefficient is zero.
    pub fn is_zero(&self) -> bool {
        self.compliance == 0.0 && self.harmonics.iter().all(|h| *h == 0.0)
    }

    /// `∂Δθ/∂q` of the harmonics at commanded value `q` (rad/rad; the compliance's rate comes
    /// from the torque's, [`crate::model::kinematics::gravity_torque_rates`]).
    pub fn harmonic_rate(&self, q: f64) -> f64 {
        let [s1, c1, s2, c2] = self.harmonics;
        let (s, c) = q.sin_cos();
        let (s_2, c_2) = (2.0 * q).sin_cos();
        s1 * c - c1 * s + 2.0 * (s2 * c_2 - c2 * s_2)
    }

    /// `Δθ` of this joint at commanded value `q` with gravity torque `tau` (rad).
    pub fn correction(&self, q: f64, tau: f64) -> f64 {
        self.correction_trig(q.sin_cos(), tau)
    }

    /// [`JointTerms::correction`] given `(sin q, cos q)`.
    pub fn correction_trig(&self, sc: (f64, f64), tau: f64) -> f64 {
        TermKind::ALL
            .into_iter()
            .map(|k| self.get(k) * k.basis_trig(sc, tau))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back_and_families_hold_their_kinds() {
        assert_eq!(
            TermFamily::parse_list("harmonics, compliance,harmonics").unwrap(),
            vec![TermFamily::Compliance, TermFamily::Harmonics]
        );
        assert_eq!(
            TermFamily::parse_list("gravity").unwrap_err().to_string(),
            "`gravity` is not one of compliance, harmonics"
        );
        for k in TermKind::ALL {
            assert!(k.family().kinds().contains(&k));
        }
        let mut t = JointTerms::default();
        for (i, k) in TermKind::ALL.into_iter().enumerate() {
            *t.get_mut(k) = i as f64 + 1.0;
        }
        assert_eq!(t.compliance, 1.0);
        assert_eq!(t.harmonics, [2.0, 3.0, 4.0, 5.0]);
    }
}
