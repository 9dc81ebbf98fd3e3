//! The Explore page's layout and its two tool bars (condition, tool,
//! obstacles; camera, traces).

use egui::{Color32, RichText};
use kilotouch_rig::RigConfig;

use crate::engine::{Condition, EngineHandle};
use crate::gui::env::PageEnv;

use super::{ExplorePage, Tool, config_obstacles};

impl super::super::Page for ExplorePage {
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let mut engine = env.engine.take();
        self.draw(ui, env, engine.as_deref_mut());
        env.engine = engine;
    }
}

impl ExplorePage {
    /// Draw the page with the engine taken out of `env`.
    fn draw(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
    ) {
        let cfg = env.rig_config;
        if let Some(e) = engine.as_deref_mut() {
            self.poll_reset(e);
        }
        let condition = engine.as_ref().map(|e| e.condition());
        if condition != self.free_condition {
            // The free agitation belongs to one condition.
            self.free_accel.clear();
            self.free_condition = condition;
        }
        self.toolbar_ui(ui, cfg, engine.as_deref_mut());
        self.camera_ui(ui);
        if let Some(m) = &self.message {
            let mut clear = false;
            ui.horizontal(|ui| {
                ui.colored_label(Color32::from_rgb(230, 150, 40), m);
                clear = ui.small_button("dismiss").clicked();
            });
            if clear {
                self.message = None;
            }
        }
        ui.separator();
        // ------------------------------------------------- scene + plots
        let avail = ui.available_size();
        let scene_side = (avail.x * 0.48).min(avail.y).max(120.0);
        ui.horizontal_top(|ui| {
            ui.vertical(|ui| {
                self.scene_ui(ui, cfg, scene_side, engine);
            });
            ui.vertical(|ui| {
                self.plots_ui(ui, avail.y);
            });
        });
    }

    /// The condition V/P/D, the scene's tool, the obstacles and Reset bead.
    fn toolbar_ui(
        &mut self,
        ui: &mut egui::Ui,
        cfg: &RigConfig,
        mut engine: Option<&mut EngineHandle>,
    ) {
        ui.horizontal_wrapped(|ui| {
            ui.label(RichText::new("Condition").strong());
            let current = engine.as_ref().map(|e| e.condition());
            for c in Condition::ALL {
                let b = ui
                    .add(egui::Button::selectable(
                        current == Some(c),
                        RichText::new(c.code()).strong().size(16.0),
                    ))
                    .on_hover_text(c.description());
                if b.clicked()
                    && let Some(e) = engine.as_deref_mut()
                {
                    e.set_condition(c);
                }
            }
            // Fixed width, that of the longest description: the toolbar wraps
            // the same way in V, P and D, so the scene below does not jump
            // when the condition changes, and no description is cut.
            let desc = current.map(|c| c.description()).unwrap_or_default();
            let font = egui::TextStyle::Body.resolve(ui.style());
            let width = Condition::ALL
                .iter()
                .map(|c| {
                    ui.painter()
                        .layout_no_wrap(c.description().to_owned(), font.clone(), Color32::WHITE)
                        .size()
                        .x
                })
                .fold(0.0, f32::max)
                + 4.0;
            ui.add_sized([width, 18.0], egui::Label::new(desc));
            ui.separator();
            ui.label(RichText::new("Tool").strong());
            ui.selectable_value(&mut self.tool, Tool::Drag, "drag trap");
            if engine
                .as_deref()
                .is_some_and(|e| e.identity().kind != kilotouch_rig::device::RigKind::Simulated)
            {
                ui.colored_label(
                    Color32::from_rgb(230, 150, 40),
                    "live rig: the trap follows the real handle, dragging here does nothing",
                );
            }
            ui.selectable_value(&mut self.tool, Tool::Place, "place obstacle")
                .on_hover_text("or Shift+click in the scene");
            ui.selectable_value(&mut self.tool, Tool::Remove, "remove obstacle")
                .on_hover_text("or Ctrl+click / right-click an obstacle");
            ui.add(
                egui::DragValue::new(&mut self.obstacle_radius_um)
                    .range(0.5..=10.0)
                    .speed(0.1)
                    .suffix(" µm"),
            )
            .on_hover_text("radius of new obstacles");
            if ui.button("Clear obstacles").clicked() {
                self.obstacles.clear();
                self.push_obstacles(engine.as_deref_mut());
            }
            if ui.button("Rig-file obstacles").clicked() {
                self.obstacles = config_obstacles(cfg);
                self.push_obstacles(engine.as_deref_mut());
            }
            if ui
                .button("Reset bead")
                .on_hover_text(
                    "put the bead back in the trap (the trap first moves off an obstacle it \
                     sits over, else the bead would be pushed out at once)",
                )
                .clicked()
                && let Some(e) = engine
            {
                self.reset_bead(cfg, e);
            }
        });
    }

    /// The camera model, the traces' length, the counters (and the sound).
    fn camera_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            ui.label(RichText::new("Camera").strong());
            ui.checkbox(&mut self.camera.model.enabled, "frame rate + latency");
            ui.add(
                egui::DragValue::new(&mut self.camera.model.fps)
                    .range(1.0..=1000.0)
                    .suffix(" fps"),
            );
            let mut lat_ms = self.camera.model.latency_s * 1e3;
            if ui
                .add(
                    egui::DragValue::new(&mut lat_ms)
                        .range(0.0..=500.0)
                        .suffix(" ms latency"),
                )
                .changed()
            {
                self.camera.model.latency_s = lat_ms * 1e-3;
            }
            ui.add(
                egui::DragValue::new(&mut self.blur_um)
                    .range(0.0..=3.0)
                    .speed(0.02)
                    .suffix(" µm blur"),
            );
            ui.add(
                egui::DragValue::new(&mut self.noise)
                    .range(0.0..=0.5)
                    .speed(0.005)
                    .prefix("noise "),
            );
            ui.separator();
            ui.add(
                egui::DragValue::new(&mut self.trace_seconds)
                    .range(0.1..=10.0)
                    .speed(0.05)
                    .suffix(" s traces"),
            );
            ui.label(format!(
                "contacts {} · escapes {}",
                self.contacts, self.escapes
            ));
            #[cfg(feature = "audio")]
            {
                ui.separator();
                let mut on = self.sound.monitor.is_some();
                if ui
                    .checkbox(&mut on, "hear the high channel")
                    .on_hover_text(
                        "play the Haptuator drive (±2 V = full scale) on the default audio output",
                    )
                    .changed()
                {
                    self.sound.set(on, self.fs);
                }
                if let Some(e) = &self.sound.error {
                    ui.colored_label(Color32::from_rgb(230, 150, 40), e);
                }
            }
        });
    }
}
