//! Where the trap is held for a passive calibration: the extra drag a known
//! surface puts on the bead at that spot, and the bias it gives the
//! stiffness κ a power-spectral calibration fits.
//!
//! A calibration fits the corner frequency f_c = κ/(2πγ) and converts it
//! with the drag γ it assumes (Stokes, with Faxén's factor for the
//! coverslip when told its distance), κ̂ = 2πγ_assumed·f_c. Near an
//! obstacle the bead's drag is larger ([`super::drag`]: Brenner's law along
//! the surface normal n, Faxén's along the tangent t, the same laws the
//! simulated tweezer steps with), so f_c is lower and κ̂ too. Along the
//! in-plane axis e (x or y) the bead's mobility is
//! μ_e = n_e²·μ⊥ + t_e²·μ∥ (exact for the diffusion coefficient the
//! spectrum's plateau measures); the drag factor is β_e = μ_free/μ_e and
//! the predicted relative error of κ̂ on that axis is 1/β_e − 1, with
//! μ_free the mobility far from obstacles (coverslip included). Wall drag
//! decays slowly (Faxén: 9/16·R/h), so a 1.5 µm bead 30 µm from an
//! obstacle's surface still calibrates ≈ 3 % soft: calibrate in free
//! solution.

use super::TweezerParams;
use super::drag::{DRAG_CLAMP_GAP_OVER_R, faxen_parallel_mobility, perpendicular_mobility};

/// Predicted relative error of κ above which a record or calibration says
/// the spot is biased (1 %).
pub const KAPPA_BIAS_WARN: f64 = 0.01;

/// The drag a known surface adds at a trap spot ([module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceDrag {
    /// Index of the nearest obstacle in the tweezer's list (`None`: no
    /// obstacle).
    pub obstacle: Option<usize>,
    /// Centre of that obstacle, m.
    pub obstacle_centre_m: [f64; 2],
    /// Gap between the bead's and the obstacle's surfaces, m (∞ without an
    /// obstacle).
    pub gap_m: f64,
    /// In-plane drag along x and y relative to the drag far from obstacles
    /// (the coverslip's Faxén factor included), β ≥ 1.
    pub drag_factor: [f64; 2],
}

impl SurfaceDrag {
    /// Predicted relative error of the κ a calibration fits on x and y,
    /// 1/β − 1 (negative: too soft).
    pub fn kappa_bias(&self) -> [f64; 2] {
        self.drag_factor.map(|b| 1.0 / b - 1.0)
    }

    /// Is either axis' predicted κ error beyond [`KAPPA_BIAS_WARN`]?
    pub fn biased(&self) -> bool {
        self.kappa_bias().iter().any(|b| b.abs() > KAPPA_BIAS_WARN)
    }

    /// A sentence for the researcher, e.g. "the trap is 5.50 µm from the
    /// surface of the obstacle at (12.0, 0.0) µm: its drag lowers f_c and
    /// biases κ by about −24 % (x) and −12 % (y)".
    pub fn describe(&self) -> String {
        let [bx, by] = self.kappa_bias();
        match self.obstacle {
            None => "no obstacle near the trap: κ is not biased by surface drag".to_owned(),
            Some(_) => format!(
                "the bead is {:.2} µm from the surface of the obstacle at ({:.1}, {:.1}) µm: \
                 its drag lowers the corner frequency and biases κ by about {:+.1} % (x) and \
                 {:+.1} % (y)",
                self.gap_m * 1e6,
                self.obstacle_centre_m[0] * 1e6,
                self.obstacle_centre_m[1] * 1e6,
                100.0 * bx,
                100.0 * by
            ),
        }
    }
}

/// The surface drag at a bead centred at `bead_m` (m) among the obstacles
/// of `p` (the nearest obstacle, as the simulated tweezer; the drag
/// formulas clamped at h/R ≥ 1.1 as there). Without obstacles the factors
/// are 1.
pub fn surface_drag(p: &TweezerParams, bead_m: [f64; 2]) -> SurfaceDrag {
    let r = p.radius_m;
    let nearest = p
        .obstacles
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let d = [bead_m[0] - o.centre_m[0], bead_m[1] - o.centre_m[1]];
            let dist = d[0].hypot(d[1]);
            (i, o, d, dist, dist - o.radius_m - r)
        })
        .min_by(|a, b| a.4.total_cmp(&b.4));
    let Some((i, o, d, dist, gap)) = nearest else {
        return SurfaceDrag {
            obstacle: None,
            obstacle_centre_m: [f64::NAN; 2],
            gap_m: f64::INFINITY,
            drag_factor: [1.0; 2],
        };
    };
    // Unit normal from the obstacle's centre to the bead (any direction at
    // the centre itself).
    let n = if dist > 0.0 {
        [d[0] / dist, d[1] / dist]
    } else {
        [1.0, 0.0]
    };
    let h = r + gap.max(DRAG_CLAMP_GAP_OVER_R * r);
    let s = r / h;
    let (m_perp, m_par) = (perpendicular_mobility(s), faxen_parallel_mobility(s));
    let factor = |e: usize| 1.0 / (n[e] * n[e] * m_perp + (1.0 - n[e] * n[e]) * m_par);
    SurfaceDrag {
        obstacle: Some(i),
        obstacle_centre_m: o.centre_m,
        gap_m: gap,
        drag_factor: [factor(0), factor(1)],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tweezer::Obstacle;
    use crate::tweezer::drag::{brenner_perpendicular, faxen_parallel};

    fn with_obstacle(x: f64, y: f64, r: f64) -> TweezerParams {
        TweezerParams {
            obstacles: vec![Obstacle {
                centre_m: [x, y],
                radius_m: r,
            }],
            ..TweezerParams::paper_default()
        }
    }

    #[test]
    fn no_obstacle_no_bias() {
        let d = surface_drag(&TweezerParams::paper_default(), [0.0, 0.0]);
        assert_eq!(d.drag_factor, [1.0, 1.0]);
        assert!(!d.biased());
        assert!(d.gap_m.is_infinite());
    }

    #[test]
    fn along_an_axis_the_factors_are_brenner_and_faxen() {
        // Obstacle on the x axis: x is the normal (Brenner), y the tangent
        // (Faxén), h = 12 − 5 = 7 µm from the bead's centre.
        let p = with_obstacle(12e-6, 0.0, 5e-6);
        let d = surface_drag(&p, [0.0, 0.0]);
        let s = 1.5 / 7.0;
        assert!((d.drag_factor[0] / brenner_perpendicular(s) - 1.0).abs() < 1e-12);
        assert!((d.drag_factor[1] / faxen_parallel(s) - 1.0).abs() < 1e-12);
        assert!((d.gap_m - 5.5e-6).abs() < 1e-15);
        // −24 % and −12 %: the default rig's spot (0, 0).
        let [bx, by] = d.kappa_bias();
        assert!(
            (bx + 0.237).abs() < 0.005 && (by + 0.120).abs() < 0.005,
            "{bx} {by}"
        );
        assert!(d.biased());
        assert!(d.describe().contains("5.50 µm"), "{}", d.describe());
        // On the diagonal both axes mix the two laws equally.
        let q = with_obstacle(10e-6, 10e-6, 5e-6);
        let e = surface_drag(&q, [0.0, 0.0]);
        assert!((e.drag_factor[0] - e.drag_factor[1]).abs() < 1e-12);
        let s = 1.5 / (200f64.sqrt() - 5.0);
        let mix = 1.0 / (0.5 * perpendicular_mobility(s) + 0.5 * faxen_parallel_mobility(s));
        assert!((e.drag_factor[0] / mix - 1.0).abs() < 1e-12);
    }

    #[test]
    fn far_away_the_bias_falls_below_the_threshold_like_faxen() {
        let p = with_obstacle(0.0, 0.0, 5e-6);
        // Faxén: bias ≈ −9/16·R/h; 1 % at h ≈ 56 R.
        let far = surface_drag(&p, [200e-6, 0.0]);
        assert!(!far.biased(), "{:?}", far.kappa_bias());
        let near = surface_drag(&p, [40e-6, 0.0]);
        assert!(near.biased(), "{:?}", near.kappa_bias());
        // Inside the contact zone the factors stay finite (clamped).
        let touching = surface_drag(&p, [6.5e-6, 0.0]);
        assert!(
            touching
                .drag_factor
                .iter()
                .all(|b| b.is_finite() && *b > 1.0)
        );
    }
}
