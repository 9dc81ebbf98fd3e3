//! The one check of a HELLO the host accepts: every announced value
//! against the device layer's bounds
//! ([`crate::device::validate_announced`], `docs/PROTOCOL.md` §5.1).

use super::frame::{Caps, Hello};
use crate::error::RigError;

/// The numeric fields of a HELLO by their protocol names.
pub fn hello_fields(h: &Hello) -> Vec<(&'static str, f64)> {
    let mut v = vec![
        ("sample_rate_hz", f64::from(h.sample_rate_hz)),
        ("watchdog_ms", f64::from(h.watchdog_ms)),
        ("batch", f64::from(h.batch)),
    ];
    match h.caps {
        Caps::Daq(c) => v.extend([
            ("encoder_counts_per_m", c.encoder_counts_per_m),
            ("accel_m_s2_per_code", c.accel_m_s2_per_code),
            ("accel_range_m_s2", c.accel_range_m_s2),
            ("force_max_n", c.force_max_n),
            ("drive_max_v", c.drive_max_v),
        ]),
        Caps::Tweezer(c) => v.push(("stiffness_n_per_m", c.stiffness_n_per_m)),
    }
    v
}

/// Checks every value of the HELLO of the device at `path`.
///
/// # Errors
/// [`RigError::Device`] naming the first field out of its bounds.
pub fn check_hello(path: &str, h: &Hello) -> Result<(), RigError> {
    crate::device::validate_announced(path, &hello_fields(h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::serial::frame::{DaqCaps, TweezerCaps};

    fn daq() -> Hello {
        let caps = DaqCaps {
            encoder_counts_per_m: 1e5,
            accel_m_s2_per_code: 1.4528e-2,
            accel_range_m_s2: 58.84,
            force_max_n: 5.0,
            drive_max_v: 2.0,
        };
        let mut h = Hello::emulator(10_000, Caps::Daq(caps), "daq", "1", "test");
        h.watchdog_ms = 100;
        h.batch = 10;
        h
    }

    /// Every field of a HELLO is checked (an invalid value of each is
    /// refused naming it); the emulators' HELLOs pass.
    #[test]
    fn every_hello_field_is_checked() {
        check_hello("p", &daq()).unwrap();
        let names: Vec<&str> = hello_fields(&daq()).iter().map(|(n, _)| *n).collect();
        assert_eq!(names.len(), 8);
        let mut t = Hello::emulator(
            1000,
            Caps::Tweezer(TweezerCaps {
                stiffness_n_per_m: 2e-5,
            }),
            "tw",
            "2",
            "test",
        );
        t.watchdog_ms = 100;
        t.batch = 1;
        check_hello("p", &t).unwrap();
        t.caps = Caps::Tweezer(TweezerCaps {
            stiffness_n_per_m: f64::NAN,
        });
        let e = check_hello("p", &t).unwrap_err().to_string();
        assert!(e.contains("stiffness_n_per_m = NaN"), "{e}");
        // Each of these fields of the DAQ's HELLO, set out of its bounds.
        type Set = fn(&mut Hello);
        let out_of_bounds: [(&str, Set); 3] = [
            ("watchdog_ms", |h| h.watchdog_ms = 0),
            ("batch", |h| h.batch = 0),
            ("sample_rate_hz", |h| h.sample_rate_hz = 1),
        ];
        for (field, set) in out_of_bounds {
            let mut h = daq();
            set(&mut h);
            let e = check_hello("p", &h).unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
    }
}
