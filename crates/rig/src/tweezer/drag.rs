//! Drag of a sphere in a viscous fluid near walls: Stokes in bulk, Faxén's
//! parallel correction and Brenner's perpendicular one (Schäffer et al.
//! 2007's approximation), with the mobility derivative the Itô drift needs.

use std::f64::consts::PI;

/// Clamp of the drag formulas near contact: the surface distance h used in
/// Faxén/Brenner is at least (1 + this)·R, i.e. h/R ≥ 1.1, the range in which
/// Schäffer's approximation is validated (and the scale of surface
/// roughness below which lubrication theory stops applying).
pub const DRAG_CLAMP_GAP_OVER_R: f64 = 0.1;
/// Stokes drag of a sphere, γ₀ = 6π η R (N·s/m).
pub fn stokes_drag(viscosity_pa_s: f64, radius_m: f64) -> f64 {
    6.0 * PI * viscosity_pa_s * radius_m
}
/// Faxén's parallel wall correction γ∥/γ₀ for s = R/h (h = centre–wall
/// distance): 1/(1 − 9/16 s + 1/8 s³ − 45/256 s⁴ − 1/16 s⁵).
pub fn faxen_parallel(s: f64) -> f64 {
    1.0 / faxen_parallel_mobility(s)
}
/// Parallel mobility ratio γ₀/γ∥ = 1/[`faxen_parallel`] (Faxén's series).
#[inline]
pub(super) fn faxen_parallel_mobility(s: f64) -> f64 {
    1.0 - 9.0 / 16.0 * s + 0.125 * s.powi(3) - 45.0 / 256.0 * s.powi(4) - 0.0625 * s.powi(5)
}
/// Perpendicular mobility ratio γ₀/γ⊥ (Schäffer et al. 2007 approximation
/// of Brenner's series), s = R/h.
pub fn perpendicular_mobility(s: f64) -> f64 {
    1.0 - 9.0 / 8.0 * s + 0.5 * s.powi(3) - 0.57 * s.powi(4)
        + 0.2 * s.powi(5)
        + 7.0 / 200.0 * s.powi(11)
        - 0.04 * s.powi(12)
}
/// d/ds of [`perpendicular_mobility`].
pub fn perpendicular_mobility_ds(s: f64) -> f64 {
    -9.0 / 8.0 + 1.5 * s * s - 2.28 * s.powi(3) + s.powi(4) + 77.0 / 200.0 * s.powi(10)
        - 0.48 * s.powi(11)
}
/// Brenner's perpendicular wall correction γ⊥/γ₀ (Schäffer's approximation,
/// within 0.1 % of the exact series for h/R ≥ 1.1), s = R/h.
pub fn brenner_perpendicular(s: f64) -> f64 {
    1.0 / perpendicular_mobility(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tweezer::TweezerParams;

    #[test]
    fn wall_corrections_match_reference_table() {
        // docs/REFERENCE-VALUES.md (h/R, parallel, perpendicular).
        let table = [
            (1.1, 2.360, 11.46),
            (1.5, 1.615, 3.205),
            (2.0, 1.386, 2.126),
            (3.0, 1.227, 1.569),
            (5.0, 1.126, 1.285),
            (10.0, 1.059, 1.126),
        ];
        for (hr, par, perp) in table {
            let s = 1.0 / hr;
            assert!(
                (faxen_parallel(s) / par - 1.0).abs() < 2e-3,
                "Faxén at h/R={hr}: {}",
                faxen_parallel(s)
            );
            // Schäffer's approximation is within 0.1 % of the exact series.
            assert!(
                (brenner_perpendicular(s) / perp - 1.0).abs() < 1.5e-3,
                "Brenner at h/R={hr}: {}",
                brenner_perpendicular(s)
            );
        }
    }

    #[test]
    fn mobility_derivative_matches_finite_difference() {
        for s in [0.05, 0.3, 0.6, 0.9, 0.99] {
            let h = 1e-6;
            let fd = (perpendicular_mobility(s + h) - perpendicular_mobility(s - h)) / (2.0 * h);
            assert!((fd - perpendicular_mobility_ds(s)).abs() < 1e-7, "s={s}");
        }
        // Lubrication limit: the mobility vanishes at contact like (1 − s).
        assert!(perpendicular_mobility(1.0).abs() < 1e-12);
    }

    #[test]
    fn stokes_and_default_corner() {
        let p = TweezerParams::paper_default();
        // γ₀ = 6π·1.0016e-3·1.5e-6 = 2.8318e-8 N·s/m.
        assert!((p.gamma0() - 2.8318e-8).abs() < 1e-11);
        // f_c = κ/(2πγ₀) ≈ 112.4 Hz for 20 pN/µm; inertia m/γ₀ ≈ 1 µs.
        assert!((p.corner_hz() / (2e-5 / (2.0 * PI * 2.8318e-8)) - 1.0).abs() < 1e-4);
        let mass = 4.0 / 3.0 * PI * p.radius_m.powi(3) * 2500.0;
        assert!(mass / p.gamma0() < 2e-6);
    }
}
