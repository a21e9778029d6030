//! The one signed-axis type: the stage axis in the flange frame (cell configuration, simulated
//! world, CSV setup header, `--stage-axis`) and the ISO 9283 approach direction, parsed once
//! at the edge.

use std::fmt;
use std::str::FromStr;

use nalgebra::Vector3;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The six signed axes by name, in the order `+x, -x, +y, -y, +z, -z`.
const NAMED: [&str; 6] = ["+x", "-x", "+y", "-y", "+z", "-z"];

/// A direction in a frame, always a finite unit vector: one of the six signed axes (`+x` …
/// `-z`) or a measured vector `X,Y,Z` (normalised); written back as it was given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignedAxis {
    unit: Vector3<f64>,
    /// Index into `NAMED`, when given by name.
    named: Option<usize>,
}

/// A stage axis that is not one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AxisError {
    /// Neither a signed axis name nor three numbers.
    #[error("`{0}` is not a number (or one of +x, -x, +y, -y, +z, -z)")]
    NotANumber(String),
    /// Not three finite numbers.
    #[error("`{0}`: expected three finite numbers X,Y,Z (or one of +x, -x, +y, -y, +z, -z)")]
    NotThreeFinite(String),
    /// A zero vector (or one too short to normalise).
    #[error("`{0}`: the stage axis must be a non-zero vector")]
    Zero(String),
}

impl SignedAxis {
    /// `+x`.
    pub const PLUS_X: SignedAxis = SignedAxis::named(0);
    /// `+y`.
    pub const PLUS_Y: SignedAxis = SignedAxis::named(2);
    /// `-z`.
    pub const MINUS_Z: SignedAxis = SignedAxis::named(5);

    const fn named(i: usize) -> SignedAxis {
        let s = if i.is_multiple_of(2) { 1.0 } else { -1.0 };
        let mut v = [0.0; 3];
        v[i / 2] = s;
        SignedAxis {
            unit: Vector3::new(v[0], v[1], v[2]),
            named: Some(i),
        }
    }

    /// Parse `+x`, `-x`, `+y`, `-y`, `+z`, `-z` (the sign is required) or a vector `X,Y,Z`, normalised (a vector already unit to 1e-12 is kept bit for bit, so a
    /// stored axis reads back exactly); a zero or non-finite vector is an error.
    pub fn parse(s: &str) -> Result<SignedAxis, AxisError> {
        let t = s.trim();
        if let Some(i) = NAMED.iter().position(|n| *n == t) {
            return Ok(SignedAxis::named(i));
        }
        let mut v = [0.0; 3];
        let mut n = 0;
        for x in t.split(',') {
            let x = x.trim();
            let value: f64 = x.parse().map_err(|_| AxisError::NotANumber(x.to_owned()))?;
            if n < 3 {
                v[n] = value;
            }
            n += 1;
        }
        if n != 3 || v.iter().any(|x| !x.is_finite()) {
            return Err(AxisError::NotThreeFinite(s.to_owned()));
        }
        SignedAxis::from_vector(Vector3::from(v)).map_err(|_| AxisError::Zero(s.to_owned()))
    }

    /// A measured direction, normalised (kept bit for bit when unit to 1e-12); a zero or
    /// non-finite vector is an error.
    pub fn from_vector(v: Vector3<f64>) -> Result<SignedAxis, AxisError> {
        let n = v.norm();
        if !(n.is_finite() && n > 1e-9) {
            return Err(AxisError::Zero(format!("{},{},{}", v.x, v.y, v.z)));
        }
        Ok(SignedAxis {
            unit: if (n - 1.0).abs() <= 1e-12 { v } else { v / n },
            named: None,
        })
    }

    /// The unit vector.
    pub fn unit(&self) -> Vector3<f64> {
        self.unit
    }

    /// The signed axis name (`+x` … `-z`), when given by name.
    pub fn name(&self) -> Option<&'static str> {
        self.named.map(|i| NAMED[i])
    }

    /// Whether it is `+x` or `-x` (`0`), `±y` (`1`) or `±z` (`2`) by name.
    pub fn is_named_along(&self, axis: usize) -> bool {
        self.named.is_some_and(|i| i / 2 == axis)
    }
}

impl fmt::Display for SignedAxis {
    /// The name, or `X,Y,Z` in shortest round-trip form.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.name() {
            Some(n) => f.write_str(n),
            None => write!(f, "{:?},{:?},{:?}", self.unit.x, self.unit.y, self.unit.z),
        }
    }
}

impl FromStr for SignedAxis {
    type Err = AxisError;
    fn from_str(s: &str) -> Result<SignedAxis, AxisError> {
        SignedAxis::parse(s)
    }
}

impl Serialize for SignedAxis {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for SignedAxis {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<SignedAxis, D::Error> {
        let s = String::deserialize(d)?;
        SignedAxis::parse(&s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_vectors_parse_to_unit_vectors() {
        assert_eq!(SignedAxis::parse("-x").unwrap().unit(), -Vector3::x());
        assert_eq!(SignedAxis::parse(" +z ").unwrap().unit(), Vector3::z());
        assert_eq!(SignedAxis::parse("+y").unwrap(), SignedAxis::PLUS_Y);
        assert_eq!(SignedAxis::parse("+x").unwrap(), SignedAxis::PLUS_X);
        let v = SignedAxis::parse("0,3,4").unwrap();
        assert_eq!((v.unit(), v.name()), (Vector3::new(0.0, 0.6, 0.8), None));
        // a unit vector is kept bit for bit
        let u = Vector3::new(0.1f64, 0.2, 0.3).normalize();
        let text = SignedAxis::from_vector(u).unwrap().to_string();
        assert_eq!(SignedAxis::parse(&text).unwrap().unit(), u);
        assert!(SignedAxis::parse("-y").unwrap().is_named_along(1));
        assert!(!SignedAxis::parse("0,1,0").unwrap().is_named_along(1));
    }

    #[test]
    fn bad_axes_are_refused_with_a_clear_error() {
        for (s, want) in [
            (
                "+w",
                "`+w` is not a number (or one of +x, -x, +y, -y, +z, -z)",
            ),
            ("0,0,0", "`0,0,0`: the stage axis must be a non-zero vector"),
            (
                "nan,0,1",
                "`nan,0,1`: expected three finite numbers X,Y,Z (or one of +x, -x, +y, -y, +z, -z)",
            ),
            (
                "inf,0,1",
                "`inf,0,1`: expected three finite numbers X,Y,Z (or one of +x, -x, +y, -y, +z, -z)",
            ),
            (
                "1,0",
                "`1,0`: expected three finite numbers X,Y,Z (or one of +x, -x, +y, -y, +z, -z)",
            ),
            (
                "y",
                "`y` is not a number (or one of +x, -x, +y, -y, +z, -z)",
            ),
            ("", "`` is not a number (or one of +x, -x, +y, -y, +z, -z)"),
        ] {
            assert_eq!(SignedAxis::parse(s).unwrap_err().to_string(), want, "{s}");
        }
        assert!(SignedAxis::from_vector(Vector3::new(f64::NAN, 0.0, 1.0)).is_err());
        assert!(SignedAxis::from_vector(Vector3::zeros()).is_err());
    }

    #[test]
    fn serde_keeps_the_spelling() {
        #[derive(Serialize, Deserialize)]
        struct T {
            axis: SignedAxis,
        }
        for text in ["axis = \"-y\"\n", "axis = \"0.0,0.6,0.8\"\n"] {
            let t: T = toml::from_str(text).unwrap();
            assert_eq!(toml::to_string(&t).unwrap(), text);
        }
        let e = toml::from_str::<T>("axis = \"0,0,0\"").err().unwrap();
        assert!(e.to_string().contains("must be a non-zero vector"), "{e}");
    }
}
