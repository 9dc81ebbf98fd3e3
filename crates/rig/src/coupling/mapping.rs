//! The hand ↔ trap mapping: where a handle position puts the trap, and what
//! force an optical force becomes at the handle. The coupling, the study's
//! participant models and the GUI's scene all use this one mapping.
//!
//! Position (master → slave): trap = offset + s·(handle − origin), per axis,
//! clamped to the trap workspace. Force (slave → master): the reaction of
//! the optical force on the trap, κ(bead − trap), times g·sign(s) at the
//! handle. With the sign, pushing the trap into an obstacle is felt as a
//! resistance whatever the mapping's orientation: the coupling is a lever
//! with position ratio s and force ratio g·sign(s), passive for g > 0.

use crate::config::CouplingConfig;
use serde::{Deserialize, Serialize};

/// Hand ↔ trap mapping (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HandMapping {
    /// Trap displacement per hand displacement s, m/m (negative mirrors).
    pub scale: f64,
    /// Hand position mapped to `trap_offset_m`, m.
    pub handle_origin_m: [f64; 2],
    /// Trap position at the origin, m.
    pub trap_offset_m: [f64; 2],
    /// Trap workspace, lower corner, m.
    pub trap_min_m: [f64; 2],
    /// Trap workspace, upper corner, m.
    pub trap_max_m: [f64; 2],
    /// Handle force per optical force g, N/N.
    pub force_scale: f64,
}

impl HandMapping {
    /// The mapping of a rig file's `[coupling]`.
    pub fn from_config(c: &CouplingConfig) -> Self {
        Self {
            scale: c.position_scale,
            handle_origin_m: c.handle_origin_m,
            trap_offset_m: c.trap_offset_m,
            trap_min_m: c.trap_min_m,
            trap_max_m: c.trap_max_m,
            force_scale: c.force_scale,
        }
    }

    /// Trap position of a hand position before the workspace clamp, m.
    #[inline]
    pub fn to_trap_unclamped(&self, hand_m: [f64; 2]) -> [f64; 2] {
        [
            self.trap_offset_m[0] + self.scale * (hand_m[0] - self.handle_origin_m[0]),
            self.trap_offset_m[1] + self.scale * (hand_m[1] - self.handle_origin_m[1]),
        ]
    }

    /// Is a trap position inside the workspace (hence finite)?
    #[inline]
    pub fn in_workspace(&self, t: [f64; 2]) -> bool {
        t[0] >= self.trap_min_m[0]
            && t[0] <= self.trap_max_m[0]
            && t[1] >= self.trap_min_m[1]
            && t[1] <= self.trap_max_m[1]
    }

    /// `t` clamped to the workspace per axis (non-finite components kept).
    pub fn clamp(&self, t: [f64; 2]) -> [f64; 2] {
        [
            t[0].clamp(self.trap_min_m[0], self.trap_max_m[0]),
            t[1].clamp(self.trap_min_m[1], self.trap_max_m[1]),
        ]
    }

    /// Trap position of a hand position, clamped to the workspace, m.
    pub fn to_trap(&self, hand_m: [f64; 2]) -> [f64; 2] {
        self.clamp(self.to_trap_unclamped(hand_m))
    }

    /// Hand position that puts the trap at `trap_m` (inside the workspace), m.
    pub fn to_hand(&self, trap_m: [f64; 2]) -> [f64; 2] {
        [
            self.handle_origin_m[0] + (trap_m[0] - self.trap_offset_m[0]) / self.scale,
            self.handle_origin_m[1] + (trap_m[1] - self.trap_offset_m[1]) / self.scale,
        ]
    }

    /// Where each trial and the Explore engine start: the trap of the hand
    /// at rest (0, 0), clamped, m.
    pub fn rest_trap_m(&self) -> [f64; 2] {
        self.to_trap([0.0, 0.0])
    }

    /// Handle force per unit of the optical force's reaction on the trap,
    /// g·sign(s), N/N.
    #[inline]
    pub fn force_gain(&self) -> f64 {
        self.force_scale.copysign(self.scale)
    }

    /// Handle force (N) of an optical force on the bead `optical_n`
    /// (κ(trap − bead), N): −g·sign(s)·optical.
    #[inline]
    pub fn to_hand_force(&self, optical_n: [f64; 2]) -> [f64; 2] {
        let k = -self.force_gain();
        [k * optical_n[0], k * optical_n[1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RigConfig;

    #[test]
    fn round_trip_and_clamp() {
        let m = HandMapping::from_config(&RigConfig::default().coupling);
        let h = [0.01, -0.005];
        let t = m.to_trap(h);
        let back = m.to_hand(t);
        assert!((back[0] - h[0]).abs() < 1e-15 && (back[1] - h[1]).abs() < 1e-15);
        let far = m.to_trap([1.0, -1.0]);
        assert_eq!(far, [m.trap_max_m[0], m.trap_min_m[1]]);
        assert_eq!(m.rest_trap_m(), m.clamp(m.trap_offset_m));
    }

    #[test]
    fn the_force_resists_in_both_orientations() {
        for s in [4e-4, -4e-4] {
            let mut c = RigConfig::default().coupling;
            c.position_scale = s;
            let m = HandMapping::from_config(&c);
            // The hand moves +x; the trap moves by s·dx and drags the bead
            // (stuck at an obstacle) behind it: optical force on the bead
            // κ(trap − bead) has the sign of s.
            let optical = [1e-12 * s.signum(), 0.0];
            let f = m.to_hand_force(optical);
            assert!(f[0] < 0.0, "scale {s}: force {f:?} must push the hand back");
        }
    }
}
