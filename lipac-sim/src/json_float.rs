//! JSON for `f64` fields that may be infinite or NaN.
//!
//! serde_json writes a non-finite `f64` as `null` and then refuses to read
//! `null` back as an `f64`: a sweep whose relative error was infinite (a
//! strategy that lit a pixel the black ground truth does not, see
//! [`relative_rmse`](crate::pathtrace::relative_rmse)) wrote a `sweep.json`
//! that `lipac sweep --replot` and `--merge` could not read. Fields marked
//! `#[serde(with = "crate::json_float")]` (or `json_float::vec` for a
//! `Vec<f64>`) write a finite value as a JSON number, as before, and a
//! non-finite one as the string `"inf"`, `"-inf"` or `"nan"`; reading takes
//! a number or one of those strings.
//!
//! ```
//! #[derive(serde::Serialize, serde::Deserialize, PartialEq, Debug)]
//! struct Row {
//!     #[serde(with = "lipac_sim::json_float")]
//!     error: f64,
//! }
//! let text = serde_json::to_string(&Row { error: f64::INFINITY }).unwrap();
//! assert_eq!(text, r#"{"error":"inf"}"#);
//! let back: Row = serde_json::from_str(&text).unwrap();
//! assert_eq!(back.error, f64::INFINITY);
//! assert_eq!(serde_json::from_str::<Row>(r#"{"error":0.25}"#).unwrap().error, 0.25);
//! ```

use std::fmt;

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::ser::{SerializeSeq, Serializer};

/// The string a non-finite value is written as.
fn name(v: f64) -> &'static str {
    if v.is_nan() {
        "nan"
    } else if v > 0.0 {
        "inf"
    } else {
        "-inf"
    }
}

/// Writes `v`: a number if finite, else `"inf"`, `"-inf"` or `"nan"`.
pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else {
        s.serialize_str(name(*v))
    }
}

/// Reads a number or one of `"inf"`, `"-inf"`, `"nan"`.
pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    d.deserialize_any(F64Visitor)
}

struct F64Visitor;

impl Visitor<'_> for F64Visitor {
    type Value = f64;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(r#"a number or "inf", "-inf", "nan""#)
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
        Ok(v)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
        Ok(v as f64)
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
        Ok(v as f64)
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
        match v {
            "inf" => Ok(f64::INFINITY),
            "-inf" => Ok(f64::NEG_INFINITY),
            "nan" => Ok(f64::NAN),
            _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
        }
    }
}

/// [`serialize`] and [`deserialize`]
/// for every element of a `Vec<f64>`.
pub mod vec {
    use super::*;

    /// Writes each element as [`super::serialize`] does.
    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        struct One(f64);
        impl serde::Serialize for One {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                super::serialize(&self.0, s)
            }
        }
        let mut seq = s.serialize_seq(Some(v.len()))?;
        for &x in v {
            seq.serialize_element(&One(x))?;
        }
        seq.end()
    }

    /// Reads an array of what [`super::deserialize`] reads.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        struct One(f64);
        impl<'de> serde::Deserialize<'de> for One {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                super::deserialize(d).map(One)
            }
        }
        struct SeqVisitor;
        impl<'de> Visitor<'de> for SeqVisitor {
            type Value = Vec<f64>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(r#"an array of numbers or "inf", "-inf", "nan""#)
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Vec<f64>, A::Error> {
                let mut v = Vec::with_capacity(a.size_hint().unwrap_or(0).min(1 << 16));
                while let Some(One(x)) = a.next_element()? {
                    v.push(x);
                }
                Ok(v)
            }
        }
        d.deserialize_seq(SeqVisitor)
    }
}

#[cfg(test)]
mod tests;
