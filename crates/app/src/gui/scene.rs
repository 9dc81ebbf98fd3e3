//! The microscope scene: what the camera sees (trap, manipulated bead,
//! obstacles), the simulated camera (frame rate and latency), the mapping
//! between screen and specimen, and the plain egui-painter fallback of the
//! wgpu renderer ([`super::scene_wgpu`]).
//!
//! **Camera.** A camera exposes frame k at t_k = k/f_cam (sample time of the
//! engine) and the frame reaches the screen at t_k + L (latency). The scene
//! shows, at engine time t, the state sampled at the newest t_k with
//! t_k + L ≤ t (sample-and-hold). The paper's participants saw the bead
//! through such a camera; with the camera model off the scene shows the
//! latest telemetry sample.

use egui::{Color32, Painter, Pos2, Rect, Stroke, pos2};
use kilotouch_rig::tweezer::Obstacle;
use std::collections::VecDeque;

/// The state of the specimen at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Snapshot {
    /// Engine time, s.
    pub t_s: f64,
    /// Bead centre, m.
    pub bead_m: [f64; 2],
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Bead held by the trap.
    pub trapped: bool,
    /// Bead in contact with an obstacle.
    pub in_contact: bool,
}

/// Camera parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraModel {
    /// Apply frame rate and latency (off = ideal camera).
    pub enabled: bool,
    /// Frame rate, Hz.
    pub fps: f64,
    /// Latency from exposure to display, s.
    pub latency_s: f64,
}

impl Default for CameraModel {
    fn default() -> Self {
        Self {
            enabled: true,
            fps: 30.0,
            latency_s: 0.05,
        }
    }
}

/// Sample-and-hold camera (module docs).
#[derive(Debug, Clone, Default)]
pub struct Camera {
    /// Parameters.
    pub model: CameraModel,
    frames: VecDeque<Snapshot>,
    next_exposure_s: f64,
    live: Snapshot,
    frame_index: u64,
}

impl Camera {
    /// A camera with these parameters.
    pub fn new(model: CameraModel) -> Self {
        Self {
            model,
            ..Default::default()
        }
    }

    /// Forget the frames (after a reconnect).
    pub fn reset(&mut self) {
        self.frames.clear();
        self.next_exposure_s = 0.0;
        self.live = Snapshot::default();
    }

    /// Feed the engine state at time `s.t_s` (monotonic).
    pub fn observe(&mut self, s: Snapshot) {
        if s.t_s < self.live.t_s {
            self.reset();
        }
        self.live = s;
        let valid = self.model.enabled
            && self.model.fps.is_finite()
            && self.model.fps > 0.0
            && self.model.latency_s.is_finite()
            && self.model.latency_s >= 0.0;
        if !valid {
            return;
        }
        if s.t_s >= self.next_exposure_s {
            self.frames.push_back(s);
            self.frame_index = (s.t_s * self.model.fps).floor() as u64;
            self.next_exposure_s = (self.frame_index + 1) as f64 / self.model.fps;
        }
        let lat = self.model.latency_s;
        while self.frames.len() >= 2 && self.frames[1].t_s + lat <= s.t_s {
            self.frames.pop_front();
        }
        // Bound the memory if latency ≫ frame period.
        while self.frames.len() > 10_000 {
            self.frames.pop_front();
        }
    }

    /// What the screen shows now (`None` before the first frame arrives).
    pub fn visible(&self) -> Option<Snapshot> {
        if !self.model.enabled {
            return (self.live.t_s > 0.0).then_some(self.live);
        }
        self.frames
            .front()
            .filter(|f| f.t_s + self.model.latency_s <= self.live.t_s)
            .copied()
    }

    /// Index of the newest exposed frame (seeds the camera noise).
    pub fn frame_index(&self) -> u64 {
        self.frame_index
    }
}

/// Screen ↔ specimen mapping: specimen y grows upwards.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Screen rectangle, points.
    pub rect: Rect,
    /// Specimen point at the rectangle's centre, µm.
    pub centre_um: [f64; 2],
    /// Micrometres per point.
    pub um_per_pt: f64,
}

impl View {
    /// A view of `rect` showing at least ±`half_um` around `centre_um`.
    pub fn fit(rect: Rect, centre_um: [f64; 2], half_um: f64) -> Self {
        let side = f64::from(rect.width().min(rect.height())).max(1.0);
        Self {
            rect,
            centre_um,
            um_per_pt: 2.0 * half_um / side,
        }
    }

    /// Specimen (m) → screen (points).
    pub fn to_screen(&self, m: [f64; 2]) -> Pos2 {
        let c = self.rect.center();
        pos2(
            c.x + ((m[0] * 1e6 - self.centre_um[0]) / self.um_per_pt) as f32,
            c.y - ((m[1] * 1e6 - self.centre_um[1]) / self.um_per_pt) as f32,
        )
    }

    /// Screen (points) → specimen (m).
    pub fn to_specimen(&self, p: Pos2) -> [f64; 2] {
        let c = self.rect.center();
        [
            (self.centre_um[0] + f64::from(p.x - c.x) * self.um_per_pt) * 1e-6,
            (self.centre_um[1] - f64::from(p.y - c.y) * self.um_per_pt) * 1e-6,
        ]
    }

    /// Length (m) → points.
    pub fn len_pt(&self, m: f64) -> f32 {
        (m * 1e6 / self.um_per_pt) as f32
    }

    /// Half width and height of the view, µm.
    pub fn half_extent_um(&self) -> [f64; 2] {
        [
            f64::from(self.rect.width()) * 0.5 * self.um_per_pt,
            f64::from(self.rect.height()) * 0.5 * self.um_per_pt,
        ]
    }
}

/// Everything a renderer needs for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFrame {
    /// Mapping.
    pub view: View,
    /// Manipulated bead centre, m.
    pub bead_m: [f64; 2],
    /// Its radius, m.
    pub bead_radius_m: f64,
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Defocus blur, µm.
    pub blur_um: f64,
    /// Camera noise amplitude (fraction of full scale).
    pub noise: f64,
    /// Camera frame index (noise seed).
    pub frame: u64,
    /// Emergency stop latched (marker turns red).
    pub estop: bool,
}

/// Largest number of beads the wgpu shader draws (manipulated bead included).
pub const MAX_BEADS: usize = 16;

/// Paint the scene with the egui painter (fallback when wgpu is not
/// available): same geometry, a simpler look (concentric circles for the
/// rim, the focus spot and one outer ring; sparse noise dots).
pub fn paint_fallback(painter: &Painter, f: &SceneFrame) {
    let rect = f.view.rect;
    painter.rect_filled(rect, 0.0, Color32::from_gray(200));
    let draw_bead = |centre: [f64; 2], r_m: f64, tint: Color32| {
        let c = f.view.to_screen(centre);
        let r = f.view.len_pt(r_m).max(1.0);
        let blur = f.view.len_pt(f.blur_um * 1e-6);
        painter.circle_stroke(
            c,
            r * 1.35 + blur,
            Stroke::new(1.0, Color32::from_gray(215)),
        );
        painter.circle_filled(c, r, Color32::from_gray(150));
        painter.circle_stroke(
            c,
            r,
            Stroke::new((0.25 * r + blur).max(1.5), Color32::from_gray(55)),
        );
        painter.circle_filled(c, (0.3 * r).max(1.0), tint);
    };
    for o in &f.obstacles {
        draw_bead(o.centre_m, o.radius_m, Color32::from_gray(245));
    }
    draw_bead(f.bead_m, f.bead_radius_m, Color32::WHITE);
    // Camera noise: a few dozen dots from a per-frame hash.
    let mut s = f.frame.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let n = (f.noise * 400.0) as usize;
    for _ in 0..n {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let x = rect.left() + rect.width() * ((s >> 40) as f32 / (1u64 << 24) as f32);
        let y = rect.top() + rect.height() * (((s >> 16) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32);
        let g = if s & 1 == 0 { 170 } else { 225 };
        painter.circle_filled(pos2(x, y), 0.8, Color32::from_gray(g));
    }
    let marker = if f.estop {
        Color32::RED
    } else {
        Color32::from_rgb(25, 215, 65)
    };
    painter.circle_stroke(
        f.view.to_screen(f.trap_m),
        f.view.len_pt(0.6e-6).max(3.0),
        Stroke::new(1.5, marker),
    );
}

/// Pack a frame into the shader's uniform block (see `scene.wgsl`):
/// 4 + 16 vec4<f32>, little-endian f32.
pub fn uniforms(f: &SceneFrame) -> [u8; UNIFORM_BYTES] {
    let mut v = [0f32; UNIFORM_BYTES / 4];
    let he = f.view.half_extent_um();
    v[..4].copy_from_slice(&[
        f.view.centre_um[0] as f32,
        f.view.centre_um[1] as f32,
        he[0] as f32,
        he[1] as f32,
    ]);
    let mut beads: Vec<[f32; 4]> = f
        .obstacles
        .iter()
        .take(MAX_BEADS - 1)
        .map(|o| {
            [
                (o.centre_m[0] * 1e6) as f32,
                (o.centre_m[1] * 1e6) as f32,
                (o.radius_m * 1e6) as f32,
                0.0,
            ]
        })
        .collect();
    beads.push([
        (f.bead_m[0] * 1e6) as f32,
        (f.bead_m[1] * 1e6) as f32,
        (f.bead_radius_m * 1e6) as f32,
        1.0,
    ]);
    v[4..8].copy_from_slice(&[
        f.blur_um as f32,
        f.noise as f32,
        (f.frame % 65_536) as f32,
        beads.len() as f32,
    ]);
    v[8..12].copy_from_slice(&[
        (f.trap_m[0] * 1e6) as f32,
        (f.trap_m[1] * 1e6) as f32,
        0.6,
        if f.estop { 1.0 } else { 0.0 },
    ]);
    for (k, b) in beads.iter().enumerate() {
        v[12 + 4 * k..16 + 4 * k].copy_from_slice(b);
    }
    let mut out = [0u8; UNIFORM_BYTES];
    for (chunk, x) in out.chunks_exact_mut(4).zip(v) {
        chunk.copy_from_slice(&x.to_le_bytes());
    }
    out
}

/// Size of the uniform block, bytes.
pub const UNIFORM_BYTES: usize = (3 + MAX_BEADS) * 16;

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp_camera(model: CameraModel, t_end: f64, fs: f64) -> Camera {
        let mut c = Camera::new(model);
        let n = (t_end * fs) as u64;
        for k in 1..=n {
            let t = k as f64 / fs;
            c.observe(Snapshot {
                t_s: t,
                bead_m: [t, 0.0],
                ..Default::default()
            });
        }
        c
    }

    #[test]
    fn camera_shows_the_newest_exposure_older_than_the_latency() {
        let fs = 10_000.0;
        for &(fps, lat) in &[(30.0, 0.05), (60.0, 0.0), (25.0, 0.2), (1000.0, 0.003)] {
            for &t_end in &[0.5, 0.7312, 1.0001] {
                let c = ramp_camera(
                    CameraModel {
                        enabled: true,
                        fps,
                        latency_s: lat,
                    },
                    t_end,
                    fs,
                );
                let v = c.visible().unwrap();
                // Newest exposure instant t_k = k/fps with t_k + L ≤ t_end;
                // the frame holds the first sample at or after t_k.
                let k = ((t_end - lat) * fps + 1e-9).floor();
                let t_k = k / fps;
                let expected = (t_k * fs - 1e-6).ceil() / fs;
                assert!(
                    (v.bead_m[0] - expected.max(1.0 / fs)).abs() < 1.5 / fs,
                    "fps {fps} lat {lat} t {t_end}: shows {} expected {expected}",
                    v.bead_m[0]
                );
                // The displayed state is never newer than t − L.
                assert!(v.t_s + lat <= t_end + 1e-12);
            }
        }
    }

    #[test]
    fn ideal_camera_shows_the_latest_sample_and_nothing_before_data() {
        let c = Camera::new(CameraModel {
            enabled: true,
            ..Default::default()
        });
        assert!(c.visible().is_none());
        let c = ramp_camera(
            CameraModel {
                enabled: false,
                ..Default::default()
            },
            0.25,
            10_000.0,
        );
        assert!((c.visible().unwrap().bead_m[0] - 0.25).abs() < 1e-12);
        // Latency longer than the run: nothing visible yet.
        let c = ramp_camera(
            CameraModel {
                enabled: true,
                fps: 30.0,
                latency_s: 1.0,
            },
            0.5,
            10_000.0,
        );
        assert!(c.visible().is_none());
    }

    #[test]
    fn view_round_trips_and_keeps_y_up() {
        let v = View::fit(
            Rect::from_min_size(pos2(10.0, 20.0), egui::vec2(400.0, 300.0)),
            [1.0, -2.0],
            15.0,
        );
        assert!((v.um_per_pt - 0.1).abs() < 1e-12);
        for m in [[0.0, 0.0], [3e-6, -7e-6], [-12e-6, 9e-6]] {
            let p = v.to_screen(m);
            let back = v.to_specimen(p);
            assert!((back[0] - m[0]).abs() < 1e-11 && (back[1] - m[1]).abs() < 1e-11);
        }
        let up = v.to_screen([1e-6, 0.0]);
        let higher = v.to_screen([1e-6, 5e-6]);
        assert!(higher.y < up.y, "specimen +y is screen up");
    }

    #[test]
    fn uniforms_pack_the_beads_and_the_trap() {
        let f = SceneFrame {
            view: View::fit(
                Rect::from_min_size(Pos2::ZERO, egui::vec2(100.0, 100.0)),
                [0.0; 2],
                20.0,
            ),
            bead_m: [1e-6, 2e-6],
            bead_radius_m: 1.5e-6,
            trap_m: [3e-6, 4e-6],
            obstacles: vec![Obstacle {
                centre_m: [12e-6, 0.0],
                radius_m: 5e-6,
            }],
            blur_um: 0.3,
            noise: 0.05,
            frame: 7,
            estop: true,
        };
        let u = uniforms(&f);
        let at =
            |i: usize| f32::from_le_bytes([u[4 * i], u[4 * i + 1], u[4 * i + 2], u[4 * i + 3]]);
        assert_eq!((at(2), at(3)), (20.0, 20.0));
        assert_eq!(at(7), 2.0, "two beads");
        assert_eq!((at(8), at(9), at(11)), (3.0, 4.0, 1.0));
        assert_eq!((at(12), at(13), at(14), at(15)), (12.0, 0.0, 5.0, 0.0));
        assert_eq!((at(16), at(17), at(18), at(19)), (1.0, 2.0, 1.5, 1.0));
    }
}
