//! Plane-vector helpers of the tasks: the norm, angle wrapping and the angle
//! between two vectors (sample-plane positions in m, forces in N).

use std::f64::consts::PI;

/// Euclidean norm of a 2-vector, √(x² + y²) (the rig crate's
/// [`kilotouch_rig::lanes::norm2`]): several times cheaper than `f64::hypot`
/// (a libm call). The task's positions (m) and forces (N) are far from the
/// over- and underflow limits of the squares (|x| ≳ 1e154 gives +∞, which
/// every comparison then treats as far or large; |x| ≲ 1e-154 loses relative
/// accuracy but not the comparisons against µm and pN scales).
pub use kilotouch_rig::lanes::norm2 as norm;

/// Wraps an angle difference to (−π, π].
#[inline]
pub fn wrap_pi(mut a: f64) -> f64 {
    if !a.is_finite() {
        return 0.0;
    }
    if a > PI || a <= -PI {
        a = a.rem_euclid(2.0 * PI);
        if a > PI {
            a -= 2.0 * PI;
        }
    }
    a
}

/// Angle between two vectors, radians in [0, π] (atan2 of the cross and dot
/// products: accurate for small and near-π angles). 0 when either vector is
/// zero.
#[inline]
pub fn angle_between(a: [f64; 2], b: [f64; 2]) -> f64 {
    let cross = a[0] * b[1] - a[1] * b[0];
    let dot = a[0] * b[0] + a[1] * b[1];
    if cross == 0.0 && dot == 0.0 {
        0.0
    } else {
        cross.abs().atan2(dot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_and_angles() {
        assert_eq!(wrap_pi(0.25), 0.25);
        assert!((wrap_pi(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_pi(-PI) - PI).abs() < 1e-12);
        assert!((wrap_pi(-1.5 * PI) - 0.5 * PI).abs() < 1e-12);
        assert_eq!(wrap_pi(f64::NAN), 0.0);
        assert!((angle_between([1.0, 0.0], [0.0, 2.0]) - PI / 2.0).abs() < 1e-15);
        assert!((angle_between([1.0, 0.0], [-1.0, 1e-9]) - PI).abs() < 1e-8);
        assert_eq!(angle_between([0.0, 0.0], [1.0, 0.0]), 0.0);
    }
}
