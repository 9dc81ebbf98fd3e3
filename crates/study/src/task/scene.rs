//! The scene of a trial: the fixed obstacle and the bead sizes
//! ([`Geometry`]), where the trap starts and, in the blind task, the
//! instructed heading ([`Scene`]), drawn from the trial's generator.

use std::f64::consts::PI;

use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::Rng;

use super::UM;
use super::vec2::norm;
use crate::protocol::Task;
use kilotouch_rig::config::{ObstacleConfig, TweezerConfig};

/// The fixed obstacle and the bead sizes (sample plane, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Obstacle centre, m.
    pub obstacle_m: [f64; 2],
    /// Obstacle radius R_o, m.
    pub obstacle_radius_m: f64,
    /// Manipulated bead radius R_b, m.
    pub bead_radius_m: f64,
}

impl Geometry {
    /// Radius of the contact circle R_c = R_o + R_b (bead centre positions
    /// at which the surfaces touch), m.
    pub fn contact_radius_m(&self) -> f64 {
        self.obstacle_radius_m + self.bead_radius_m
    }

    /// Vector from the obstacle centre to `p`, m.
    #[inline]
    pub fn rel(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] - self.obstacle_m[0], p[1] - self.obstacle_m[1]]
    }

    /// Surface gap g = |p − c| − R_c of a bead centred at `p`, m (negative
    /// = overlap).
    #[inline]
    pub fn gap_m(&self, p: [f64; 2]) -> f64 {
        norm(self.rel(p)) - self.contact_radius_m()
    }

    /// The micro-world of this geometry in a rig file's `[tweezer]`
    /// section: the manipulated bead's radius, the trap's escape distance
    /// `escape_distance_m` and the one obstacle (the simulated trial's
    /// tweezer and `kilotouch emulate tweezer --protocol` alike).
    pub fn apply_to(&self, tc: &mut TweezerConfig, escape_distance_m: f64) {
        tc.radius_m = self.bead_radius_m;
        tc.escape_distance_m = escape_distance_m;
        tc.obstacles = vec![ObstacleConfig {
            x_m: self.obstacle_m[0],
            y_m: self.obstacle_m[1],
            radius_m: self.obstacle_radius_m,
        }];
    }

    /// The protocol's geometry with the obstacle centred at the origin.
    pub fn of_protocol(task: &Task) -> Self {
        let (obstacle, bead) = match task {
            Task::Circling(t) => (t.obstacle_radius_um, t.bead_radius_um),
            Task::BlindNavigation(t) => (t.obstacle_radius_um, t.bead_radius_um),
        };
        Self {
            obstacle_m: [0.0; 2],
            obstacle_radius_m: obstacle * UM,
            bead_radius_m: bead * UM,
        }
    }

    /// Outward unit normal of the obstacle at the direction of `p` (the
    /// x axis when `p` is the centre).
    #[inline]
    pub fn normal(&self, p: [f64; 2]) -> [f64; 2] {
        let r = self.rel(p);
        let d = norm(r);
        if d > 0.0 && d.is_finite() {
            [r[0] / d, r[1] / d]
        } else {
            [1.0, 0.0]
        }
    }
}

/// The layout of one trial: geometry, where the bead starts and (blind
/// task) the heading the participant is told to move along. Drawn from the
/// trial's task generator ([`crate::seeds::STREAM_TASK`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Obstacle and bead sizes.
    pub geometry: Geometry,
    /// Bead (= trap) position at the start, m.
    pub start_m: [f64; 2],
    /// Unit vector of the instructed initial direction (blind task; for
    /// circling the direction towards the obstacle).
    pub heading: [f64; 2],
}

pub use crate::protocol::CIRCLING_START_GAP_M;

/// Fraction of the widest heading cone that still hits the obstacle from
/// which blind-navigation headings are drawn (so that a straight movement
/// along the instructed heading collides).
pub const BLIND_HEADING_CONE_FRACTION: f64 = 0.6;

/// Uniform in [0, 1) from 53 random bits.
#[inline]
pub fn unit_uniform(rng: &mut ChaCha20Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1_u64 << 53) as f64
}

impl Scene {
    /// Draws the scene of a trial around the start position `start_m`
    /// (the trap position of the handle's rest position).
    ///
    /// * Circling: the obstacle centre at distance R_c + 2 µm from the start
    ///   in a uniformly random direction.
    /// * Blind navigation: the obstacle centre at distance
    ///   R_c + `start_distance` in a uniformly random direction φ; the
    ///   heading points from the start to the centre, rotated by an angle
    ///   uniform in ±0.6·asin(R_c / (R_c + start_distance)) so that the
    ///   straight line along it hits the contact circle.
    pub fn draw(task: &Task, start_m: [f64; 2], rng: &mut ChaCha20Rng) -> Self {
        let phi = 2.0 * PI * unit_uniform(rng);
        let u = [phi.cos(), phi.sin()];
        match task {
            Task::Circling(_) => {
                let geometry = Geometry::of_protocol(task);
                let d = geometry.contact_radius_m() + CIRCLING_START_GAP_M;
                Self {
                    geometry: Geometry {
                        obstacle_m: [start_m[0] + d * u[0], start_m[1] + d * u[1]],
                        ..geometry
                    },
                    start_m,
                    heading: u,
                }
            }
            Task::BlindNavigation(t) => {
                let geometry = Geometry::of_protocol(task);
                let rc = geometry.contact_radius_m();
                let d = rc + t.start_distance_um * UM;
                let cone = BLIND_HEADING_CONE_FRACTION * (rc / d).asin();
                let off = cone * (2.0 * unit_uniform(rng) - 1.0);
                let h = phi + off;
                Self {
                    geometry: Geometry {
                        obstacle_m: [start_m[0] + d * u[0], start_m[1] + d * u[1]],
                        ..geometry
                    },
                    start_m,
                    heading: [h.cos(), h.sin()],
                }
            }
        }
    }
}
