//! Fig. 10: blind navigation — trajectories of the bead that collided with
//! the obstacle, superposed in the obstacle's frame. The study is `kilotouch
//! study simulate --protocol blind` (the simulated operator, condition D,
//! raw files on), written to `DIR/study-blind`; the trajectories are read
//! back from its raw files as the Results page reads them
//! ([`read_trajectory`]); each trial's obstacle is its scene, drawn again
//! from the trial's key ([`TrialEngine::setup`]).

use super::style::{self, Figure, Frame, err};
use super::{Claim, PaperError, PaperOptions, write_csv};
use kilotouch_rig::coupling::LoopChain;
use kilotouch_study::protocol::{Protocol, Task};
use kilotouch_study::results::{StudyResults, read_trajectory};
use kilotouch_study::runner::{RunnerConfig, TrialEngine};
use kilotouch_study::seeds::Phase;
use kilotouch_study::task::sim_station::SimStation;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Trajectories drawn (the paper shows five).
pub const DRAWN: usize = 5;
/// Points per trajectory drawn.
const POINTS: usize = 3000;

/// One drawn trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Drawn {
    /// Participant id.
    pub participant: String,
    /// Participant index (0-based).
    pub participant_index: u32,
    /// Trial number.
    pub trial: u32,
    /// Trial successful.
    pub success: bool,
    /// Bead centre relative to the obstacle centre, µm.
    pub xy_um: Vec<[f64; 2]>,
    /// Smallest surface gap along the path, µm.
    pub min_gap_um: f64,
    /// Retreat-direction error, degrees (none: no retreat).
    pub retreat_err_deg: Option<f64>,
}

/// The data of Fig. 10.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig10 {
    /// Trajectories drawn.
    pub drawn: Vec<Drawn>,
    /// Obstacle radius, µm.
    pub obstacle_radius_um: f64,
    /// Bead radius, µm.
    pub bead_radius_um: f64,
    /// Contact tolerance (surface gap), µm.
    pub contact_gap_um: f64,
    /// Largest successful retreat error, degrees.
    pub success_angle_deg: f64,
    /// Test trials.
    pub n_test: usize,
    /// Test trials that collided.
    pub n_collided: usize,
    /// Successful test trials.
    pub n_success: usize,
    /// Participants.
    pub participants: u32,
}

/// Remove a previous study folder written by `kilotouch paper` (it holds
/// `session.json`), so that a second run starts afresh.
pub(crate) fn fresh_study_dir(dir: &Path) -> Result<(), PaperError> {
    if dir.join(kilotouch_study::export::SESSION_FILE).exists() {
        std::fs::remove_dir_all(dir).map_err(|e| PaperError::Io {
            path: dir.to_path_buf(),
            source: e,
        })?;
    }
    Ok(())
}

/// The built-in protocol `name` with the paper run's study seed, and
/// without practice trials in quick mode.
///
/// # Errors
/// An unknown built-in protocol.
pub(crate) fn paper_protocol(name: &str, opts: &PaperOptions) -> Result<Protocol, PaperError> {
    let mut protocol = Protocol::builtin(name).map_err(|e| PaperError::Results(e.to_string()))?;
    protocol.seeds.study = opts.seed;
    if opts.quick {
        protocol.training.practice_trials = 0;
    }
    Ok(protocol)
}

/// Simulate `protocol` into `dir` (afresh; as-designed chain, default
/// fidelity, the paper run's threads) and read the folder's results: the one
/// study run behind Figs. 10, 11 and 12.
///
/// # Errors
/// Study and file errors.
pub(crate) fn simulate_study(
    opts: &PaperOptions,
    protocol: &Protocol,
    dir: &Path,
    runner: RunnerConfig,
    progress: &mut dyn FnMut(f64, &str),
) -> Result<StudyResults, PaperError> {
    fresh_study_dir(dir)?;
    let sim = kilotouch_study::simulate::SimulateOptions {
        rig: opts.rig.clone(),
        runner,
        threads: opts.threads,
        ..kilotouch_study::simulate::SimulateOptions::new(protocol.clone(), dir)
    };
    kilotouch_study::simulate::simulate(&sim, &mut |d, t| {
        progress(d as f64 / t.max(1) as f64, &format!("{d}/{t} trials"))
    })?;
    StudyResults::load(dir).map_err(|e| PaperError::Results(e.to_string()))
}

/// The participant index of an id `P01`, `P1`… (`protocol.rs` numbers
/// participants from 1).
pub(crate) fn participant_index(id: &str) -> Result<u32, PaperError> {
    id.strip_prefix('P')
        .and_then(|n| n.parse::<u32>().ok())
        .and_then(|n| n.checked_sub(1))
        .ok_or_else(|| PaperError::Results(format!("unexpected participant id `{id}`")))
}

impl Fig10 {
    /// Simulate the blind-navigation study (quick: 5 participants × 3
    /// trials, no practice; full: the protocol as shipped) and pick the
    /// trajectories.
    ///
    /// # Errors
    /// Study and file errors.
    pub fn simulate(
        opts: &PaperOptions,
        progress: &mut dyn FnMut(f64, &str),
    ) -> Result<Self, PaperError> {
        let mut protocol = paper_protocol("blind", opts)?;
        if opts.quick {
            protocol.trials_per_session = 3;
        }
        let Task::BlindNavigation(task) = protocol.task.clone() else {
            return Err(PaperError::Results(
                "the blind protocol is not a blind-navigation task".into(),
            ));
        };
        let dir = opts.out.join("study-blind");
        let res = simulate_study(opts, &protocol, &dir, RunnerConfig::default(), progress)?;
        let engine = TrialEngine::new(
            SimStation::with_chain(&opts.rig, LoopChain::as_designed(&opts.rig)?)?,
            RunnerConfig::default(),
        )?;
        let test: Vec<_> = res.rows.iter().filter(|r| r.phase == Phase::Test).collect();
        let collided: Vec<_> = test
            .iter()
            .filter(|r| r.time_to_collision_s.is_some())
            .collect();
        // The first collided trial of each participant, then the next ones,
        // in plan order, up to DRAWN (no selection on success).
        let mut order: Vec<&&kilotouch_study::export::TrialRow> = Vec::new();
        for round in 0.. {
            let mut added = false;
            for p in &res.summary.participants {
                if let Some(r) = collided.iter().filter(|r| &r.participant == p).nth(round) {
                    order.push(r);
                    added = true;
                }
            }
            if !added || order.len() >= DRAWN {
                break;
            }
        }
        order.truncate(DRAWN);
        let rc = task.obstacle_radius_um + task.bead_radius_um;
        let mut drawn = Vec::new();
        for r in order {
            let pi = participant_index(&r.participant)?;
            let setup = engine.setup(&protocol, r.key(pi));
            let c = setup.scene.geometry.obstacle_m;
            let t = read_trajectory(&dir.join(&r.raw_file), r.trial, r.success, POINTS)
                .map_err(|e| PaperError::Results(e.to_string()))?;
            let xy_um: Vec<[f64; 2]> = t
                .bead_um
                .iter()
                .map(|p| [p[0] - c[0] * 1e6, p[1] - c[1] * 1e6])
                .collect();
            let min_gap_um = xy_um
                .iter()
                .map(|p| p[0].hypot(p[1]) - rc)
                .fold(f64::INFINITY, f64::min);
            drawn.push(Drawn {
                participant: r.participant.clone(),
                participant_index: pi,
                trial: r.trial,
                success: r.success,
                xy_um,
                min_gap_um,
                retreat_err_deg: r.retreat_angle_err_deg,
            });
        }
        Ok(Self {
            drawn,
            obstacle_radius_um: task.obstacle_radius_um,
            bead_radius_um: task.bead_radius_um,
            contact_gap_um: protocol.tolerances.contact_gap_um,
            success_angle_deg: task.success_angle_deg,
            n_test: test.len(),
            n_collided: collided.len(),
            n_success: test.iter().filter(|r| r.success).count(),
            participants: protocol.participants,
        })
    }

    /// The paper's statements about Fig. 10, checked.
    pub fn claims(&self) -> Vec<Claim> {
        let gap = self
            .drawn
            .iter()
            .map(|d| d.min_gap_um)
            .fold(f64::NEG_INFINITY, f64::max);
        // Retreat errors of the drawn trajectories, sorted (a trajectory
        // that never left the obstacle counts as infinitely wrong).
        let mut errs: Vec<f64> = self
            .drawn
            .iter()
            .map(|d| d.retreat_err_deg.unwrap_or(f64::INFINITY))
            .collect();
        errs.sort_by(f64::total_cmp);
        let within = errs
            .iter()
            .filter(|e| **e <= self.success_angle_deg)
            .count();
        let median = errs.get(errs.len() / 2).copied().unwrap_or(f64::NAN);
        let rate = self.n_success as f64 / self.n_test.max(1) as f64;
        vec![
            Claim::new(
                "10",
                &format!(
                    "each of the {} drawn trajectories reaches the obstacle: largest closest surface gap",
                    self.drawn.len()
                ),
                "volunteers blindly steered a micro-bead until it collided with an obstacle (§4.2, Fig. 10)",
                gap,
                "µm",
                &format!(
                    "≤ {} µm (the protocol's contact tolerance), {} trajectories drawn",
                    self.contact_gap_um, DRAWN
                ),
                gap <= self.contact_gap_um && self.drawn.len() == DRAWN,
            ),
            Claim::new(
                "10",
                &format!(
                    "the drawn trajectories leave along the surface normal: median retreat-direction error ({within} of {} within the success angle)",
                    errs.len()
                ),
                "they had to move away from the obstacle in a direction normal to the surface; the volunteers consistently succeeded at this task to a considerable degree (§4.2)",
                median,
                "°",
                &format!(
                    "≤ {}° (the protocol's success angle)",
                    self.success_angle_deg
                ),
                median <= self.success_angle_deg,
            ),
            Claim::new(
                "10",
                &format!(
                    "successful trials ({} of {} test trials, {} collided, {} participants)",
                    self.n_success, self.n_test, self.n_collided, self.participants
                ),
                "the volunteers consistently succeeded at this task to a considerable degree (§4.2)",
                100.0 * rate,
                "%",
                "≥ 70 %",
                rate >= 0.7,
            ),
        ]
    }

    /// Write `fig10.csv`: one row per drawn point
    /// (`trajectory,participant_index,trial,success,x_um,y_um`), positions
    /// relative to the obstacle centre.
    ///
    /// # Errors
    /// File errors.
    pub fn write_csv(&self, path: &Path) -> Result<(), PaperError> {
        let mut cols: [Vec<f64>; 6] = Default::default();
        for (k, d) in self.drawn.iter().enumerate() {
            for p in &d.xy_um {
                cols[0].push(k as f64);
                cols[1].push(f64::from(d.participant_index));
                cols[2].push(f64::from(d.trial));
                cols[3].push(f64::from(u8::from(d.success)));
                cols[4].push(p[0]);
                cols[5].push(p[1]);
            }
        }
        write_csv(
            path,
            &[
                "trajectory",
                "participant_index",
                "trial",
                "success",
                "x_um",
                "y_um",
            ],
            &[&cols[0], &cols[1], &cols[2], &cols[3], &cols[4], &cols[5]],
        )
    }
}

/// Draw trajectories (µm, obstacle at the origin) with the obstacle and the
/// contact circle — Fig. 10 and the Results page's export.
///
/// # Errors
/// Drawing errors.
pub fn draw_trajectories<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    paths: &[(String, Vec<[f64; 2]>)],
    obstacle_radius_um: Option<f64>,
    contact_radius_um: Option<f64>,
) -> Result<(), String> {
    let r = contact_radius_um.unwrap_or(0.0);
    let pts = paths.iter().flat_map(|p| p.1.iter());
    let mut m = r * 1.2;
    let (mut cx, mut cy) = (0.0, 0.0);
    if obstacle_radius_um.is_none() {
        // No obstacle frame: centre on the data.
        let xs = style::bounds(pts.clone().map(|p| p[0]), 0.0).unwrap_or((-1.0, 1.0));
        let ys = style::bounds(pts.clone().map(|p| p[1]), 0.0).unwrap_or((-1.0, 1.0));
        cx = 0.5 * (xs.0 + xs.1);
        cy = 0.5 * (ys.0 + ys.1);
    }
    for p in pts {
        m = m.max((p[0] - cx).abs()).max((p[1] - cy).abs());
    }
    let m = m * 1.08 + 0.5;
    let frame = Frame::FIGURE;
    let mut chart = frame.chart(root, title, cx - m..cx + m, cy - m..cy + m)?;
    frame
        .mesh(&mut chart, "x (µm)", "y (µm)")
        .draw()
        .map_err(err)?;
    let circle = |rad: f64| -> Vec<(f64, f64)> {
        (0..=180)
            .map(|k| {
                let a = 2.0 * std::f64::consts::PI * k as f64 / 180.0;
                (rad * a.cos(), rad * a.sin())
            })
            .collect()
    };
    if let Some(ro) = obstacle_radius_um {
        chart
            .draw_series(std::iter::once(Polygon::new(
                circle(ro),
                style::GREY.mix(0.35).filled(),
            )))
            .map_err(err)?
            .label(format!("obstacle (radius {ro} µm)"))
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 6), (x + 24, y + 6)], style::GREY.mix(0.5).filled())
            });
    }
    if let Some(rc) = contact_radius_um {
        chart
            .draw_series(DashedLineSeries::new(
                circle(rc),
                5,
                4,
                style::SUM.stroke_width(1),
            ))
            .map_err(err)?
            .label("bead centre at contact")
            .legend(style::legend_line(style::SUM, 1));
    }
    for (i, (name, p)) in paths.iter().enumerate() {
        let c = style::cycle_color(i);
        chart
            .draw_series(LineSeries::new(
                p.iter().map(|q| (q[0], q[1])),
                c.stroke_width(2),
            ))
            .map_err(err)?
            .label(name.clone())
            .legend(style::legend_line(c, 2));
        if let Some(s) = p.first() {
            chart
                .draw_series(std::iter::once(Circle::new((s[0], s[1]), 6, c.filled())))
                .map_err(err)?;
        }
        if let Some(e) = p.last() {
            chart
                .draw_series(std::iter::once(TriangleMarker::new(
                    (e[0], e[1]),
                    8,
                    c.filled(),
                )))
                .map_err(err)?;
        }
    }
    style::legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

impl Figure for Fig10 {
    fn size(&self) -> (u32, u32) {
        (900, 900)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let paths: Vec<(String, Vec<[f64; 2]>)> = self
            .drawn
            .iter()
            .map(|d| {
                (
                    format!(
                        "{} trial {}{}",
                        d.participant,
                        d.trial,
                        d.retreat_err_deg
                            .map_or(String::new(), |a| format!(", retreat {a:.0}° off normal"))
                    ),
                    d.xy_um.clone(),
                )
            })
            .collect();
        draw_trajectories(
            root,
            "Fig. 10 — Blind navigation: trajectories that collided (● start, ▲ end)",
            &paths,
            Some(self.obstacle_radius_um),
            Some(self.obstacle_radius_um + self.bead_radius_um),
        )
    }
}
