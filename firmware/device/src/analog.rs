//! The board's conversions between protocol codes and converter values
//! (docs/FIRMWARE.md, "Scales"): every output is offset binary around
//! mid-scale, so code 0 is the middle of the converter's range, which the
//! amplifier stage maps to zero force or drive.

use kilotouch_proto::flag;

/// 12-bit DAC value of an output code: 2048 + code · 2047/32767, rounded
/// half away from zero (code −32768 is treated as −32767): 1 … 4095.
pub fn dac12(code: i16) -> u16 {
    let c = i32::from(code.max(-32767));
    let num = c * 2047;
    let q = (num + if num >= 0 { 16383 } else { -16383 }) / 32767;
    (2048 + q) as u16
}

/// PWM compare value of an output code for a timer period of `arr + 1`
/// counts: mid-scale (arr + 1)/2 plus code · (arr + 1)/2 / 32767, within
/// 0 … arr + 1.
pub fn pwm_duty(code: i16, arr: u16) -> u16 {
    let half = (i64::from(arr) + 1) / 2;
    let c = i64::from(code.max(-32767));
    let d = half + c * half / 32767;
    d.clamp(0, i64::from(arr) + 1) as u16
}

/// Accelerometer code of a 12-bit ADC reading with the zero-g reading
/// `zero`: one code per ADC step; `CLIPPED` when the reading sits on a
/// rail of the converter.
pub fn accel_code(raw: u16, zero: u16) -> (i16, u8) {
    let raw = raw.min(4095);
    let f = if raw == 0 || raw == 4095 {
        flag::CLIPPED
    } else {
        0
    };
    ((i32::from(raw) - i32::from(zero)) as i16, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converters_are_offset_binary_around_zero() {
        assert_eq!(dac12(0), 2048);
        assert_eq!(dac12(32767), 4095);
        assert_eq!(dac12(-32767), 1);
        assert_eq!(dac12(i16::MIN), 1);
        // Monotonic, and symmetric about mid-scale.
        for c in [-30000i16, -100, -9, -8, 1, 8, 9, 100, 30000] {
            assert!(dac12(c) <= dac12(c + 1));
            assert_eq!(i32::from(dac12(c)) - 2048, 2048 - i32::from(dac12(-c)));
        }
        assert_eq!(pwm_duty(0, 8399), 4200);
        assert_eq!(pwm_duty(32767, 8399), 8400);
        assert_eq!(pwm_duty(-32767, 8399), 0);
        assert_eq!(accel_code(2048, 2048), (0, 0));
        assert_eq!(accel_code(4095, 2048), (2047, flag::CLIPPED));
        assert_eq!(accel_code(0, 2050), (-2050, flag::CLIPPED));
    }
}
