//! Explore page: free manipulation of the bead in the microscope scene,
//! V/P/D switched live, obstacles, and the live plots (handle force and tip
//! acceleration traces, the acceleration histogram of the paper's Fig. 9 e/g,
//! the acceleration spectrum).
//!
//! Dragging in the scene does what the real handle would: the pointer sets
//! the *hand* position h = o_h + (p − o_t)/s (the coupling's inverse: p the
//! pointed trap position, o_t the trap offset, o_h the handle origin, s the
//! position scale); the simulated hand drags the finger and handle through
//! the plant, and the coupling moves the trap from the measured handle.

use egui::Color32;
use kilotouch_dsp::spectral::Spectrum;
use kilotouch_rig::RigConfig;
use kilotouch_rig::tweezer::Obstacle;

use crate::engine::{Condition, EngineHandle, TelemetrySample, flags};
use crate::gui::plot::{self, AxisReadout, AxisScale, LiveTraces, Ring, Trace};
use crate::gui::scene::{self, Camera, CameraModel, Snapshot, View};

mod controls;
mod scene_view;

/// What a primary click/drag in the scene does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tool {
    /// Drag the trap (through the hand and the handle).
    Drag,
    /// Click to place an obstacle.
    Place,
    /// Click an obstacle to remove it.
    Remove,
}

/// What the Explore page's plots showed last frame: their axes and the
/// agitation's standard deviations (egui_plot paints tick labels as text,
/// so the tests read them here).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlotReadouts {
    /// Force trace, y axis.
    pub force: AxisReadout,
    /// Acceleration trace, y axis.
    pub accel: AxisReadout,
    /// Histogram, x axis.
    pub histogram: AxisReadout,
    /// SD of the tip acceleration x over the last second, m/s².
    pub sd_now_m_s2: Option<f64>,
    /// SD over the last second of samples without contact, m/s².
    pub sd_free_m_s2: Option<f64>,
}

/// Half width of the scene, µm.
const VIEW_HALF_UM: f64 = 24.0;

/// The Explore page.
#[derive(Debug)]
pub struct ExplorePage {
    /// Live traces.
    pub traces: LiveTraces,
    /// The camera.
    pub camera: Camera,
    /// Latest telemetry sample.
    pub last: Option<TelemetrySample>,
    /// Obstacles as the user arranged them.
    pub obstacles: Vec<Obstacle>,
    /// Click tool.
    pub tool: Tool,
    /// Radius of new obstacles, µm.
    pub obstacle_radius_um: f64,
    /// Defocus blur, µm.
    pub blur_um: f64,
    /// Camera noise amplitude.
    pub noise: f64,
    /// Length of the traces, s.
    pub trace_seconds: f64,
    /// Use the wgpu renderer for the scene (false: painter fallback).
    pub gpu: bool,
    /// Last view (pointer ↔ specimen).
    pub view: Option<View>,
    /// Hand position last sent, m.
    pub hand_m: [f64; 2],
    spectrum: Option<Spectrum>,
    spectrum_age: f64,
    hist_range: f32,
    /// Tip acceleration x of the last samples without contact (1 s), m/s²:
    /// the free agitation the histogram's SD is compared with.
    free_accel: Ring,
    /// A Reset bead waiting for the trap to reach this clear spot (m), and
    /// the frames waited.
    pending_reset: Option<([f64; 2], u32)>,
    /// Condition the free samples were taken in (cleared on a change).
    free_condition: Option<Condition>,
    /// The accelerometer's quantisation step, m/s² (histogram bins).
    accel_lsb: f64,
    force_scale: AxisScale,
    accel_scale: AxisScale,
    /// What the plots' axes showed last frame (tests read them).
    readouts: PlotReadouts,
    /// Why the Pantograph force sent is zero (outputs held, condition V).
    force_note: Option<&'static str>,
    escapes: u64,
    contacts: u64,
    message: Option<String>,
    fs: f64,
    /// Optional sound (`audio` feature): the Haptuator drive played on an
    /// output device, so a user without a Haptuator hears the high channel.
    #[cfg(feature = "audio")]
    sound: Sound,
}

/// The high channel on the default audio output (`audio` feature).
#[cfg(feature = "audio")]
#[derive(Debug, Default)]
struct Sound {
    monitor: Option<kilotouch_rig::audio::AudioMonitor>,
    /// Haptuator drive samples (V) collected during one `ingest`, pushed to
    /// the monitor's lock-free ring in one call.
    buf: Vec<f64>,
    error: Option<String>,
}

#[cfg(feature = "audio")]
impl Sound {
    /// Full scale of the played signal: ±2 V of Haptuator drive.
    const FULL_SCALE_V: f64 = 2.0;

    fn set(&mut self, on: bool, fs: f64) {
        self.error = None;
        self.monitor = None;
        if on {
            let mut cfg = kilotouch_rig::audio::MonitorConfig::new(None, fs);
            cfg.gain = 1.0 / Self::FULL_SCALE_V;
            match kilotouch_rig::audio::AudioMonitor::open(&cfg) {
                Ok(m) => self.monitor = Some(m),
                Err(e) => self.error = Some(format!("cannot open the audio output: {e}")),
            }
        }
    }
}

impl ExplorePage {
    /// New page for a rig at `fs` Hz with these obstacles.
    pub fn new(cfg: &RigConfig, camera: CameraModel) -> Self {
        let fs = cfg.rig.sample_rate_hz;
        Self {
            traces: LiveTraces::new(fs, 10.0),
            camera: Camera::new(camera),
            last: None,
            obstacles: config_obstacles(cfg),
            tool: Tool::Drag,
            obstacle_radius_um: 5.0,
            blur_um: 0.25,
            noise: 0.04,
            trace_seconds: 2.0,
            gpu: false,
            view: None,
            hand_m: cfg.coupling.handle_origin_m,
            spectrum: None,
            spectrum_age: f64::INFINITY,
            hist_range: 0.0,
            free_accel: Ring::new(fs.ceil().max(1.0) as usize),
            free_condition: None,
            pending_reset: None,
            accel_lsb: cfg.accelerometer.lsb_m_s2,
            force_scale: AxisScale::default(),
            accel_scale: AxisScale::default(),
            readouts: PlotReadouts::default(),
            force_note: None,
            escapes: 0,
            contacts: 0,
            message: None,
            fs,
            #[cfg(feature = "audio")]
            sound: Sound::default(),
        }
    }

    /// Reset for a new engine/rig.
    pub fn reset(&mut self, cfg: &RigConfig) {
        let fs = cfg.rig.sample_rate_hz;
        self.traces = LiveTraces::new(fs, 10.0);
        self.camera.reset();
        self.last = None;
        self.obstacles = config_obstacles(cfg);
        self.hand_m = cfg.coupling.handle_origin_m;
        self.spectrum = None;
        self.free_accel = Ring::new(fs.ceil().max(1.0) as usize);
        self.accel_lsb = cfg.accelerometer.lsb_m_s2;
        self.fs = fs;
    }

    /// Reset bead: at once when the trap is clear of the obstacles;
    /// otherwise the hand first moves the trap to the nearest spot clear of
    /// them ([`clear_spot`]) and the reset follows when the telemetry shows
    /// the trap there ([`Self::poll_reset`]): a bead put back inside an
    /// obstacle would be pushed out of the trap at once.
    pub(super) fn reset_bead(&mut self, cfg: &RigConfig, e: &mut EngineHandle) {
        let trap = self.last.map_or([0.0; 2], |s| s.trap_m);
        let clearance = cfg.tweezer.radius_m + 0.5e-6;
        match clear_spot(trap, &self.obstacles, clearance) {
            None => {
                let _ = e.send(crate::engine::Command::ResetBead);
                self.pending_reset = None;
            }
            Some(spot) => {
                let hand = Self::hand_for_trap(cfg, spot);
                self.hand_m = hand;
                e.set_hand(hand);
                self.pending_reset = Some((spot, 0));
            }
        }
    }

    /// Send a deferred Reset bead once the trap has reached its clear spot
    /// (within 0.2 µm), or after 3 s of frames at most.
    pub(super) fn poll_reset(&mut self, e: &mut EngineHandle) {
        let Some((spot, frames)) = self.pending_reset else {
            return;
        };
        let arrived = self
            .last
            .is_some_and(|s| (s.trap_m[0] - spot[0]).hypot(s.trap_m[1] - spot[1]) < 0.2e-6);
        if arrived || frames > 180 {
            let _ = e.send(crate::engine::Command::ResetBead);
            self.pending_reset = None;
        } else {
            self.pending_reset = Some((spot, frames + 1));
        }
    }

    /// What the plots showed last frame (axes, SD numbers).
    pub fn readouts(&self) -> &PlotReadouts {
        &self.readouts
    }

    /// Read all waiting telemetry (called by the shell every frame, whatever
    /// page is shown, so that the queue never fills).
    pub fn ingest(&mut self, engine: &mut EngineHandle) -> usize {
        let fs = self.fs;
        let traces = &mut self.traces;
        let camera = &mut self.camera;
        let last = &mut self.last;
        let (esc, con) = (&mut self.escapes, &mut self.contacts);
        let free = &mut self.free_accel;
        #[cfg(feature = "audio")]
        let (playing, sound_buf) = (self.sound.monitor.is_some(), &mut self.sound.buf);
        let n = engine.drain_telemetry(|s| {
            traces.push(s);
            #[cfg(feature = "audio")]
            if playing {
                sound_buf.push(s.output.haptuator_v);
            }
            camera.observe(Snapshot {
                t_s: s.seq as f64 / fs,
                bead_m: s.bead_m,
                trap_m: s.trap_m,
                trapped: s.has(flags::TRAPPED),
                in_contact: s.has(flags::IN_CONTACT),
            });
            if s.has(flags::ESCAPED) {
                *esc += 1;
            }
            if s.has(flags::CONTACT_START) {
                *con += 1;
            }
            if !s.has(flags::IN_CONTACT) {
                free.push(s.accel_m_s2[0] as f32);
            }
            *last = Some(*s);
        });
        #[cfg(feature = "audio")]
        if let Some(m) = &mut self.sound.monitor {
            // Never blocks: what does not fit in the ring is dropped (and
            // counted by the monitor).
            m.push(&self.sound.buf);
            self.sound.buf.clear();
        }
        n
    }

    /// Hand position (m) that puts the trap at `trap_m` (the rig crate's
    /// hand mapping, inverted).
    pub fn hand_for_trap(cfg: &RigConfig, trap_m: [f64; 2]) -> [f64; 2] {
        kilotouch_rig::coupling::HandMapping::from_config(&cfg.coupling).to_hand(trap_m)
    }

    pub(super) fn place_obstacle(&mut self, at: [f64; 2], cfg: &RigConfig) -> Result<(), String> {
        if self.obstacles.len() >= scene::MAX_BEADS - 1 {
            return Err(format!("at most {} obstacles", scene::MAX_BEADS - 1));
        }
        let r = self.obstacle_radius_um * 1e-6;
        if !(r.is_finite() && r > 0.0) {
            return Err("obstacle radius must be > 0".into());
        }
        let bead_r = cfg.tweezer.radius_m;
        let clear = |c: [f64; 2], rr: f64| {
            ((at[0] - c[0]).powi(2) + (at[1] - c[1]).powi(2)).sqrt() > r + rr
        };
        if let Some(s) = &self.last
            && (!clear(s.bead_m, bead_r + 0.5e-6) || !clear(s.trap_m, bead_r + 0.5e-6))
        {
            return Err("too close to the bead: place obstacles away from it".into());
        }
        if self
            .obstacles
            .iter()
            .any(|o| !clear(o.centre_m, o.radius_m))
        {
            return Err("overlaps another obstacle".into());
        }
        self.obstacles.push(Obstacle {
            centre_m: at,
            radius_m: r,
        });
        Ok(())
    }

    pub(super) fn remove_obstacle(&mut self, at: [f64; 2]) -> bool {
        let hit = self.obstacles.iter().position(|o| {
            ((at[0] - o.centre_m[0]).powi(2) + (at[1] - o.centre_m[1]).powi(2)).sqrt() <= o.radius_m
        });
        if let Some(i) = hit {
            self.obstacles.remove(i);
        }
        hit.is_some()
    }

    pub(super) fn push_obstacles(&mut self, engine: Option<&mut EngineHandle>) {
        if let Some(e) = engine
            && let Err(err) = e.set_obstacles(&self.obstacles)
        {
            self.message = Some(format!("obstacles not applied: {err}"));
        }
    }

    pub(super) fn plots_ui(&mut self, ui: &mut egui::Ui, height: f32) {
        let fs = self.traces.fs();
        let secs = self.trace_seconds;
        let h = ((height - 70.0) / 3.0).max(100.0);
        let fx = self.traces.last(Trace::ForceX, secs).to_vec();
        let fy = self.traces.last(Trace::ForceY, secs).to_vec();
        if let Some(n) = self.force_note {
            ui.colored_label(Color32::from_rgb(230, 150, 40), n);
        }
        self.readouts.force = plot::trace_plot(
            ui,
            "force",
            h,
            "N",
            &mut self.force_scale,
            &[
                (
                    "Pantograph force sent x",
                    Color32::from_rgb(90, 170, 255),
                    &fx,
                ),
                ("y", Color32::from_rgb(255, 150, 60), &fy),
            ],
            fs,
            false,
        );
        let ax = self.traces.last(Trace::AccelX, secs).to_vec();
        self.readouts.accel = plot::trace_plot(
            ui,
            "accel",
            h,
            "m/s²",
            &mut self.accel_scale,
            &[("tip acceleration x", Color32::from_rgb(120, 220, 120), &ax)],
            fs,
            true,
        );
        // Histogram of the last second; spectrum of the last ~1.6 s (5 Hz refresh).
        let hist = self.traces.last(Trace::AccelX, 1.0).to_vec();
        let peak = hist
            .iter()
            .filter(|v| v.is_finite())
            .fold(0f32, |m, v| m.max(v.abs()));
        // ±4 SD of the last second (the peak when it is all one value), so
        // the distribution fills the plot instead of a sliver of ±peak.
        let spread = plot::sd(&hist).map_or(peak, |sd| (4.0 * sd) as f32);
        let want = plot::nice_range(if spread > 0.0 { spread } else { peak });
        // Hysteresis: widen at once, narrow only when 2.5× too wide.
        if want > self.hist_range || want * 2.5 < self.hist_range {
            self.hist_range = want;
        }
        let mut free = Vec::new();
        self.free_accel.last_into(self.free_accel.len(), &mut free);
        self.readouts.sd_now_m_s2 = plot::sd(&hist);
        self.readouts.sd_free_m_s2 = plot::sd(&free);
        let dt = f64::from(ui.input(|i| i.stable_dt));
        self.spectrum_age += dt;
        if self.spectrum_age > 0.2 {
            let n = 16_384.min(self.traces.len());
            let x = self.traces.last(Trace::AccelX, n as f64 / fs).to_vec();
            self.spectrum = plot::spectrum(&x, fs, 1024);
            self.spectrum_age = 0.0;
        }
        let (lsb, range) = (self.accel_lsb, self.hist_range);
        let (now, free_sd) = (self.readouts.sd_now_m_s2, self.readouts.sd_free_m_s2);
        let mut hist_axis = AxisReadout::default();
        ui.columns(2, |c| {
            agitation_ui(&mut c[0], now, free_sd);
            hist_axis = plot::histogram_plot(
                &mut c[0],
                "hist",
                h,
                "tip acceleration x",
                "m/s²",
                &hist,
                range,
                lsb,
            );
            c[1].add(egui::Label::new("acceleration spectrum, dB re 1 (m/s²)²/Hz").truncate());
            plot::spectrum_plot(&mut c[1], "spectrum", h, self.spectrum.as_ref());
        });
        self.readouts.histogram = hist_axis;
    }
}

/// The agitation's standard deviation now and free, beside the histogram
/// (the paper's Fig. 9 e/g: contact narrows the distribution).
fn agitation_ui(ui: &mut egui::Ui, now: Option<f64>, free: Option<f64>) {
    let fmt = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| plot::format_si(v, "m/s²"));
    let ratio = match (now, free) {
        (Some(n), Some(f)) if f > 0.0 => format!(" (now/free {:.2})", n / f),
        _ => String::new(),
    };
    ui.add(egui::Label::new(format!("SD now {} · free {}", fmt(now), fmt(free))).truncate())
        .on_hover_text(format!(
            "standard deviation of the tip acceleration x{ratio}: now = the last second; free = \
             the last second without contact (in this condition). Pressing against an obstacle \
             narrows the agitation (the paper's Fig. 9 e/g)."
        ));
}

/// The nearest spot to `trap` (m) whose distance to every obstacle's
/// centre is at least its radius plus `clearance` (m), or `None` when
/// `trap` is already such a spot: searched on rings around `trap` every
/// 0.25 µm out to 50 µm, 64 directions each (the first clear point of the
/// nearest ring), so clusters of touching obstacles are left too.
pub fn clear_spot(trap: [f64; 2], obstacles: &[Obstacle], clearance: f64) -> Option<[f64; 2]> {
    let clear = |p: [f64; 2]| {
        obstacles
            .iter()
            .all(|o| (p[0] - o.centre_m[0]).hypot(p[1] - o.centre_m[1]) >= o.radius_m + clearance)
    };
    if clear(trap) {
        return None;
    }
    (1..=200).find_map(|k| {
        let d = 0.25e-6 * f64::from(k);
        (0..64).find_map(|j| {
            let a = std::f64::consts::TAU * f64::from(j) / 64.0;
            let p = [trap[0] + d * a.cos(), trap[1] + d * a.sin()];
            clear(p).then_some(p)
        })
    })
}

/// The obstacles of a rig file.
pub fn config_obstacles(cfg: &RigConfig) -> Vec<Obstacle> {
    cfg.tweezer
        .obstacles
        .iter()
        .map(|o| Obstacle {
            centre_m: [o.x_m, o.y_m],
            radius_m: o.radius_m,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reset_spot_leaves_every_obstacle_with_the_clearance() {
        let obs = [
            Obstacle {
                centre_m: [12e-6, 0.0],
                radius_m: 5e-6,
            },
            // Touching the first one on its right.
            Obstacle {
                centre_m: [22e-6, 0.0],
                radius_m: 5e-6,
            },
        ];
        let c = 2e-6;
        // Already clear: nothing to do.
        assert_eq!(clear_spot([0.0, 0.0], &obs, c), None);
        // Over the first obstacle, next to the second: out of both.
        let p = clear_spot([13e-6, 0.0], &obs, c).unwrap();
        for o in &obs {
            let d = (p[0] - o.centre_m[0]).hypot(p[1] - o.centre_m[1]);
            assert!(d >= o.radius_m + c, "{p:?} is {d} from {:?}", o.centre_m);
        }
        // At an obstacle's centre: the first direction (+x), just outside.
        let q = clear_spot([12e-6, 0.0], &obs[..1], c).unwrap();
        assert!((q[0] - 19.0e-6).abs() < 0.26e-6 && q[1] == 0.0, "{q:?}");
    }
}
