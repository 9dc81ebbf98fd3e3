//! The researcher's units at the edges of the code: trap stiffness in pN/µm,
//! displacement sensitivity in µm/V and force sensitivity in pN/V. Inside the
//! code every quantity is SI (N/m, m/V, N/V, names ending `_n_per_m`,
//! `_m_per_v`, `_n_per_v`); these conversions are for the command line,
//! printed text, the GUI and files.
//!
//! **Files.** A serialised SI field keeps its key and unit on disk with
//! `#[serde(rename = "kappa_pn_um", with = "kilotouch_rig::units::pn_per_um")]`
//! (the modules [`pn_per_um`], [`um_per_v`], [`pn_per_v`]; for `f64` and
//! `[f64; 2]`). Writing multiplies by the exact power of ten; reading
//! divides by it (correctly rounded).
//!
//! **Last bits.** With an exact float parser (serde_json's
//! `float_roundtrip`, which the study crate enables), a file this code wrote
//! reads back and is written again byte for byte. A value written otherwise (a hand edit, a file from when
//! the code held pN/µm) comes back as it was too, except where the file's
//! grid of numbers is finer than the SI one (about 3 % of values in pN/µm
//! or µm/V, 6 % in pN/V, all near the top of their binary octave): no SI
//! `f64` maps back to such a value, and it is written one unit in the last
//! place away (the tests measure both). A quantity computed in SI and
//! written as `value * 1e6` (κ and R_d of a fit, the stability report's
//! stiffnesses) has the bits it had when computed in pN/µm; one computed
//! from them (standard errors, R_f = R_d κ, the two axes' weighted κ) may
//! differ from that in its last digit.

/// N/m → pN/µm.
#[inline]
pub fn to_pn_per_um(n_per_m: f64) -> f64 {
    n_per_m * 1e6
}

/// pN/µm → N/m.
#[inline]
pub fn from_pn_per_um(pn_per_um: f64) -> f64 {
    pn_per_um / 1e6
}

/// m/V → µm/V.
#[inline]
pub fn to_um_per_v(m_per_v: f64) -> f64 {
    m_per_v * 1e6
}

/// µm/V → m/V.
#[inline]
pub fn from_um_per_v(um_per_v: f64) -> f64 {
    um_per_v / 1e6
}

/// N/V → pN/V.
#[inline]
pub fn to_pn_per_v(n_per_v: f64) -> f64 {
    n_per_v * 1e12
}

/// pN/V → N/V.
#[inline]
pub fn from_pn_per_v(pn_per_v: f64) -> f64 {
    pn_per_v / 1e12
}

/// A value the serde modules convert element by element.
pub trait Scaled: Sized {
    /// `f` applied to every element.
    fn map_each(&self, f: fn(f64) -> f64) -> Self;
}

impl Scaled for f64 {
    fn map_each(&self, f: fn(f64) -> f64) -> Self {
        f(*self)
    }
}

impl<const N: usize> Scaled for [f64; N] {
    fn map_each(&self, f: fn(f64) -> f64) -> Self {
        self.map(f)
    }
}

macro_rules! file_unit {
    ($name:ident, $unit:literal, $si:literal, $to:ident, $from:ident) => {
        #[doc = concat!("Serde `with` module: an SI field (", $si, ") written and read in ", $unit, ".")]
        pub mod $name {
            use super::Scaled;
            use serde::{Deserialize, Deserializer, Serialize, Serializer};

            #[doc = concat!("Write the SI value (", $si, ") in ", $unit, ".")]
            pub fn serialize<T: Scaled + Serialize, S: Serializer>(
                v: &T,
                s: S,
            ) -> Result<S::Ok, S::Error> {
                v.map_each(super::$to).serialize(s)
            }

            #[doc = concat!("Read a value in ", $unit, " as SI (", $si, ").")]
            pub fn deserialize<'de, T: Scaled + Deserialize<'de>, D: Deserializer<'de>>(
                d: D,
            ) -> Result<T, D::Error> {
                T::deserialize(d).map(|v| v.map_each(super::$from))
            }
        }
    };
}

file_unit!(pn_per_um, "pN/µm", "N/m", to_pn_per_um, from_pn_per_um);
file_unit!(um_per_v, "µm/V", "m/V", to_um_per_v, from_um_per_v);
file_unit!(pn_per_v, "pN/V", "N/V", to_pn_per_v, from_pn_per_v);

#[cfg(test)]
mod tests {
    use super::*;
    use serde::{Deserialize, Serialize};

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Rec {
        #[serde(rename = "kappa_pn_um", with = "pn_per_um")]
        kappa_n_per_m: f64,
        #[serde(rename = "rd_um_per_v", with = "um_per_v")]
        rd_m_per_v: [f64; 2],
        #[serde(rename = "rf_pn_per_v", with = "pn_per_v")]
        rf_n_per_v: f64,
    }

    fn ulps(a: f64, b: f64) -> u64 {
        a.to_bits().abs_diff(b.to_bits())
    }

    #[test]
    fn files_keep_their_keys_and_units() {
        let text = r#"{"kappa_pn_um":20.4,"rd_um_per_v":[2.0,1.9],"rf_pn_per_v":40.8}"#;
        let r: Rec = serde_json::from_str(text).unwrap();
        assert_eq!(r.kappa_n_per_m, 20.4 / 1e6);
        assert_eq!(r.rd_m_per_v, [2.0 / 1e6, 1.9 / 1e6]);
        assert_eq!(r.rf_n_per_v, 40.8 / 1e12);
        assert_eq!(serde_json::to_string(&r).unwrap(), text);
        // A value computed in SI is written as `value * 1e6`.
        let k = 2.0 * std::f64::consts::PI * 2.83e-8 * 112.37;
        let r = Rec {
            kappa_n_per_m: k,
            ..r
        };
        let v: serde_json::Value = serde_json::to_value(&r).unwrap();
        assert_eq!(v["kappa_pn_um"].as_f64(), Some(k * 1e6));
    }

    #[test]
    fn read_and_written_back_within_one_ulp_and_mostly_exact() {
        // Log-uniform over 1e-3..1e5 pN/µm with every mantissa bit random.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let n = 100_000;
        let mut moved = [0usize; 2];
        for _ in 0..n {
            let x = 10f64.powf(-3.0 + 8.0 * next());
            for (i, (to, from)) in [
                (
                    to_pn_per_um as fn(f64) -> f64,
                    from_pn_per_um as fn(f64) -> f64,
                ),
                (to_pn_per_v, from_pn_per_v),
            ]
            .into_iter()
            .enumerate()
            {
                let back = to(from(x));
                assert!(ulps(back, x) <= 1, "{x} → {back}");
                moved[i] += usize::from(back != x);
            }
        }
        let frac = moved.map(|m| m as f64 / n as f64);
        assert!(frac[0] < 0.04 && frac[1] < 0.07, "{frac:?}");
        // What this code writes reads back to a value written identically.
        for _ in 0..n {
            let y = 10f64.powf(-12.0 + 11.0 * next());
            for (to, from) in [
                (
                    to_pn_per_um as fn(f64) -> f64,
                    from_pn_per_um as fn(f64) -> f64,
                ),
                (to_pn_per_v, from_pn_per_v),
            ] {
                assert_eq!(to(from(to(y))), to(y), "{y}");
            }
        }
        // Short decimal values, as typed into a file, and the paper's ones.
        for x in [20.0, 20.4, 2.0, 0.5, 100.0, 1000.0, 1.9] {
            assert_eq!(to_pn_per_um(from_pn_per_um(x)), x);
        }
    }
}
