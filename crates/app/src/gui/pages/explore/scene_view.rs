//! The Explore page's scene: pointer input (drag the trap, place and
//! remove obstacles) and the picture with its overlays.

use egui::{Color32, Sense};
use kilotouch_rig::RigConfig;

use crate::engine::EngineHandle;
use crate::gui::scene::{self, SceneFrame, Snapshot, View};
use crate::gui::scene_wgpu::SceneCallback;

use super::{ExplorePage, Tool, VIEW_HALF_UM};

impl ExplorePage {
    pub(super) fn scene_ui(
        &mut self,
        ui: &mut egui::Ui,
        cfg: &RigConfig,
        side: f32,
        mut engine: Option<&mut EngineHandle>,
    ) {
        let (rect, resp) = ui.allocate_exact_size(egui::vec2(side, side), Sense::click_and_drag());
        let view = View::fit(rect, [0.0, 0.0], VIEW_HALF_UM);
        self.view = Some(view);
        self.scene_input(ui, &resp, view, cfg, engine.as_deref_mut());
        // Picture.
        let estop = engine
            .as_ref()
            .and_then(|e| e.health())
            .is_some_and(|h| h.safety == crate::engine::SafetyState::EStop);
        self.force_note = match engine.as_ref().and_then(|e| e.health()) {
            None => Some("no rig: no force"),
            Some(h) if h.safety != crate::engine::SafetyState::Enabled || !h.running => {
                Some("outputs held at zero: no force is sent")
            }
            Some(h) if !h.condition.haptic() => Some("V (vision only): no force is sent"),
            Some(_) => None,
        };
        let shown = self.camera.visible();
        let painter = ui.painter_at(rect);
        let Some(snap) = shown else {
            painter.rect_filled(rect, 0.0, Color32::from_gray(40));
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                if engine.is_some() {
                    "waiting for the camera…"
                } else {
                    "rig disconnected"
                },
                egui::FontId::proportional(16.0),
                Color32::LIGHT_GRAY,
            );
            return;
        };
        let frame = SceneFrame {
            view,
            bead_m: snap.bead_m,
            bead_radius_m: cfg.tweezer.radius_m,
            trap_m: snap.trap_m,
            obstacles: self.obstacles.clone(),
            blur_um: self.blur_um,
            noise: self.noise,
            frame: self.camera.frame_index(),
            estop,
        };
        if self.gpu {
            painter.add(SceneCallback::paint_callback(&frame));
        } else {
            scene::paint_fallback(&painter, &frame);
        }
        self.overlays(&painter, rect, view, &snap, estop);
        resp.on_hover_text(
            "drag: move the trap · Shift+click: place obstacle · Ctrl+click or right-click: remove",
        );
    }

    /// The pointer on the scene: place or remove an obstacle, or drag the
    /// trap (through the hand position the coupling maps to it).
    fn scene_input(
        &mut self,
        ui: &egui::Ui,
        resp: &egui::Response,
        view: View,
        cfg: &RigConfig,
        mut engine: Option<&mut EngineHandle>,
    ) {
        let mods = ui.input(|i| i.modifiers);
        if let Some(p) = resp.interact_pointer_pos() {
            let at = view.to_specimen(p);
            let place = resp.clicked() && (self.tool == Tool::Place || mods.shift);
            let remove = (resp.clicked() && (self.tool == Tool::Remove || mods.command))
                || resp.secondary_clicked();
            if place {
                match self.place_obstacle(at, cfg) {
                    Ok(()) => self.push_obstacles(engine.as_deref_mut()),
                    Err(e) => self.message = Some(e),
                }
            } else if remove {
                if self.remove_obstacle(at) {
                    self.push_obstacles(engine.as_deref_mut());
                }
            } else if self.tool == Tool::Drag
                && !mods.shift
                && !mods.command
                && (resp.dragged() || resp.is_pointer_button_down_on())
            {
                let hand = Self::hand_for_trap(cfg, at);
                self.hand_m = hand;
                if let Some(e) = engine {
                    e.set_hand(hand);
                }
            }
        }
    }

    /// The scale bar, the bead's state and the camera model over the picture.
    fn overlays(
        &self,
        painter: &egui::Painter,
        rect: egui::Rect,
        view: View,
        snap: &Snapshot,
        estop: bool,
    ) {
        let bar_um = 10.0;
        let y = rect.bottom() - 14.0;
        let x0 = rect.left() + 14.0;
        let x1 = x0 + view.len_pt(bar_um * 1e-6);
        painter.line_segment(
            [egui::pos2(x0, y), egui::pos2(x1, y)],
            egui::Stroke::new(3.0, Color32::BLACK),
        );
        painter.text(
            egui::pos2(x0, y - 4.0),
            egui::Align2::LEFT_BOTTOM,
            "10 µm",
            egui::FontId::proportional(12.0),
            Color32::BLACK,
        );
        let mut status = Vec::new();
        if !snap.trapped {
            status.push("BEAD LOST — move the trap back over it or Reset bead");
        }
        if snap.in_contact {
            status.push("contact");
        }
        if estop {
            status.push("EMERGENCY STOP");
        }
        if !status.is_empty() {
            painter.text(
                rect.left_top() + egui::vec2(8.0, 8.0),
                egui::Align2::LEFT_TOP,
                status.join(" · "),
                egui::FontId::proportional(14.0),
                Color32::from_rgb(200, 30, 30),
            );
        }
        let cam = if self.camera.model.enabled {
            format!(
                "camera {:.0} fps, {:.0} ms",
                self.camera.model.fps,
                1e3 * self.camera.model.latency_s
            )
        } else {
            "ideal camera".to_owned()
        };
        painter.text(
            rect.right_bottom() - egui::vec2(8.0, 6.0),
            egui::Align2::RIGHT_BOTTOM,
            cam,
            egui::FontId::proportional(11.0),
            Color32::from_gray(30),
        );
    }
}
