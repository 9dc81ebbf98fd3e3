//! The simulated operator ([`SimOperator`]): a seeded model of a person
//! that performs both tasks through the hand position only, from what a
//! [`Participant`] observes ([`crate::participant`]); [`SimCohort`] gives
//! each participant of a study their own operator.
//!
//! Perception (each channel with its own delay and threshold):
//!
//! * *Force* (kinesthetic, low band): the handle force low-passed at
//!   `force_lowpass_hz`, delayed by `haptic_delay_s`, felt when its
//!   magnitude exceeds `force_threshold_n`; magnitude perceived with a
//!   per-trial gain error of SD `force_weber` (Weber fraction), direction
//!   with SD `force_direction_sd_deg`.
//! * *Vibration* (Pacinian): the in-plane acceleration weighted by the
//!   P channel's U-shaped threshold curve `pacinian`
//!   ([`crate::vibrotactile::PacinianCurve`]: flat 40–300 Hz in
//!   acceleration at 0.17 m/s² RMS for the median participant); short
//!   (`vibration_short_s`) and long (`vibration_long_s`) mean-square
//!   envelopes. A *vibration transient* (the collision spike of paper
//!   Fig. 9d) is detected when the short envelope exceeds the detection
//!   threshold and the long one by the RMS ratio `vibration_change_ratio`.
//!   The *agitation* (the bead's Brownian motion, paper §4.1) is the
//!   envelope over `agitation_window_s`: once it has been felt in free space
//!   (its level is remembered while it is felt), an RMS drop by
//!   `agitation_drop_ratio` is perceived as *quieting* (the bead pressed on
//!   a surface, paper Fig. 9f–g) and its return above the level ÷ √ratio as
//!   *resuming* (contact lost). A participant who never feels the
//!   agitation (threshold above it, or too little of it rendered) has no
//!   such cue.
//! * *Vision*: each camera frame is perceived `visual_delay_s` after it is
//!   displayed, with Gaussian localisation noise `visual_noise_m` on each
//!   position; surfaces are seen touching when the seen gap is below
//!   `visual_contact_gap_m`.
//!
//! Control (identical in every condition): contact is *believed* when force
//! is felt, a vibration transient was detected within `vibration_memory_s`,
//! the agitation is quiet, or contact is seen — unless the agitation resumed
//! within `vibration_memory_s` (the fresher haptic percept overrides the
//! delayed image: "helping her(him) to anticipate and adjust", paper §4.3). *Circling*: the commanded trap point is
//! c + (R_c + d)·(cos θ, sin θ); without believed contact d decreases at
//! `approach_speed_m_s`; with felt force d is servoed towards the force goal
//! `force_goal_n` (gain `force_gain_m_per_n_s`); with seen contact d is
//! corrected once per perceived frame towards the visual push goal
//! `visual_push_goal_m` (fraction `visual_gain`); θ advances at
//! `circling_speed_m_s`/R_c while contact is believed. *Blind navigation*:
//! move along the instructed heading at `blind_speed_m_s` until contact is
//! believed, then retreat at `retreat_speed_m_s` along the perceived force
//! direction (or straight back without a felt force). The hand target
//! passes through signal-dependent motor noise (an Ornstein–Uhlenbeck
//! process, SD `motor_noise_m` + `motor_noise_gain`·|hand speed|, Harris &
//! Wolpert 1998) and a critically damped second-order "arm" at
//! `arm_bandwidth_hz`.
//!
//! *Attention lapses* ([`crate::lapse`]): a Poisson process whose rate
//! grows with the time on task since the block began (the trial's
//! [`TrialBrief::time_on_task_s`]), λ₀ ≈ 6 /h for the median rested
//! participant at the start of a block, doubling over 10 min on task, as
//! the rested psychomotor vigilance test counts lapses (responses
//! ≥ 500 ms); a lapse lasts `lapse_min_s` plus an exponential, 0.6 s on
//! average. During a lapse the hand holds still: the plan's trap point
//! stays where it was when the lapse began and nothing perceived is acted
//! on (the arm, the motor noise and the hand's passive impedance against
//! the device's force go on); afterwards the plan resumes from where it
//! was. Lapses come from their own random stream of the trial's generator.
//!
//! Parameters, their sources and the model's limits: `docs/STUDY.md` §13.

use std::f64::consts::PI;

use kilotouch_dsp::filter::Sos;
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::SeedableRng;
use serde::{Deserialize, Serialize};

use crate::export::TaskKind;
use crate::lapse::{LapseModel, LapseSchedule};
use crate::participant::{Observation, Participant, TrialBrief, VisualFrame};
use crate::protocol::{CIRCLING_START_GAP_M, Protocol, Task};
use crate::seeds::TrialKey;
use crate::seeds::{STREAM_LAPSE, SplitMix64, TRAIT_DOMAIN, splitmix64_mix};
use crate::task::{UM, angle_between, norm, unit_uniform};
use crate::vibrotactile::PacinianCurve;
use kilotouch_rig::coupling::HandMapping;

/// Parameters of the simulated operator (SI units; see the module docs and
/// `docs/STUDY.md` §13 for sources).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OperatorParams {
    /// Delay from a displayed frame to its use, s (visuomotor delay
    /// ≈ 100–200 ms).
    pub visual_delay_s: f64,
    /// Localisation noise per seen position (sample plane), m.
    pub visual_noise_m: f64,
    /// Seen surfaces touch below this gap, m (optical resolution of the
    /// display ≈ 0.2 µm).
    pub visual_contact_gap_m: f64,
    /// Delay of the haptic percepts, s (long-latency reflex 50–100 ms).
    pub haptic_delay_s: f64,
    /// Low-pass of the force percept, Hz.
    pub force_lowpass_hz: f64,
    /// Force detection threshold at the hand, N.
    pub force_threshold_n: f64,
    /// Weber fraction of force magnitude (SD of the per-trial gain error).
    pub force_weber: f64,
    /// SD of the perceived force direction, degrees.
    pub force_direction_sd_deg: f64,
    /// Vibrotactile (Pacinian) threshold curve: weighting corners and the
    /// detection threshold, m/s² RMS of the weighted acceleration.
    pub pacinian: PacinianCurve,
    /// Short envelope time constant, s.
    pub vibration_short_s: f64,
    /// Long (baseline) envelope time constant, s.
    pub vibration_long_s: f64,
    /// Envelope change (RMS ratio) detected as an event.
    pub vibration_change_ratio: f64,
    /// How long a vibration event keeps contact believed, s.
    pub vibration_memory_s: f64,
    /// Time constant of the agitation's mean-square envelope, s (default
    /// 0.05 s: a change of a vibration already felt is resolved in tens of
    /// milliseconds, gaps in vibrotactile noise from ≈ 10 to 40 ms, Van
    /// Doren, Gescheider & Verrillo 1990; the 0.5–1 s temporal summation of
    /// the P channel, Verrillo 1965, concerns detecting a weak vibration,
    /// not following a felt one).
    pub agitation_window_s: f64,
    /// RMS drop of the felt agitation perceived as quieting (contact)
    /// (default 1.69 = 1.3²: two intensity difference thresholds of ≈ 1.3
    /// in amplitude, 2.3 dB, Gescheider et al. 1990).
    pub agitation_drop_ratio: f64,
    /// Radial approach speed without believed contact, m/s (sample plane).
    pub approach_speed_m_s: f64,
    /// Tangential speed while circling, m/s (sample plane).
    pub circling_speed_m_s: f64,
    /// Force goal at the hand while in contact, N ("push lightly").
    pub force_goal_n: f64,
    /// Force servo gain, m of trap per N of error per s.
    pub force_gain_m_per_n_s: f64,
    /// Visual push goal: trap this far inside the bead's radius, m.
    pub visual_push_goal_m: f64,
    /// Fraction of the visual push error corrected per perceived frame.
    pub visual_gain: f64,
    /// Blind task: speed along the heading, m/s.
    pub blind_speed_m_s: f64,
    /// Blind task: retreat speed, m/s.
    pub retreat_speed_m_s: f64,
    /// Motor noise floor (hand coordinates), m.
    pub motor_noise_m: f64,
    /// Signal-dependent motor noise: SD per hand speed, s.
    pub motor_noise_gain: f64,
    /// Correlation time of the motor noise, s.
    pub motor_noise_tau_s: f64,
    /// Bandwidth of the arm's second-order response, Hz.
    pub arm_bandwidth_hz: f64,
    /// Rate of attention lapses at the start of a block (time on task 0),
    /// per hour of task (a Poisson process, [`crate::lapse`]). Default
    /// 6 /h, the median of the population's log-normal spread
    /// ([`TraitSpread::lapse_rate_ln_sd`]): with the growth below, about
    /// 1.5 lapses in a 10-min block, as rested adults have in the 10-min
    /// psychomotor vigilance test (1–3 responses ≥ 500 ms; Basner & Dinges
    /// 2011; `docs/STUDY.md` §13).
    pub lapse_rate_per_h: f64,
    /// Relative increase of the lapse rate per 10 min on task since the
    /// block began (time-on-task effect, Lim & Dinges 2008); the rate is
    /// back at `lapse_rate_per_h` after a break. Default 1 (twice the rate
    /// after 10 min).
    pub lapse_growth_per_10min: f64,
    /// Mean lapse duration, s (default 0.6 s: a PVT lapse is a response
    /// ≥ 500 ms against ≈ 250 ms normally, attention away ≳ 0.25 s).
    pub lapse_mean_s: f64,
    /// Shortest lapse, s (durations are this plus an exponential; default
    /// 0.25 s).
    pub lapse_min_s: f64,
}

impl Default for OperatorParams {
    fn default() -> Self {
        Self {
            visual_delay_s: 0.15,
            visual_noise_m: 0.05e-6,
            visual_contact_gap_m: 0.2e-6,
            haptic_delay_s: 0.06,
            force_lowpass_hz: 5.0,
            force_threshold_n: 0.1,
            force_weber: 0.10,
            force_direction_sd_deg: 12.0,
            pacinian: PacinianCurve::default(),
            vibration_short_s: 0.02,
            vibration_long_s: 0.5,
            vibration_change_ratio: 3.0,
            vibration_memory_s: 0.3,
            agitation_window_s: 0.05,
            agitation_drop_ratio: 1.69,
            approach_speed_m_s: 1.5e-6,
            circling_speed_m_s: 3.0e-6,
            force_goal_n: 0.3,
            force_gain_m_per_n_s: 5.0e-6,
            visual_push_goal_m: 0.15e-6,
            visual_gain: 0.08,
            blind_speed_m_s: 2.0e-6,
            retreat_speed_m_s: 2.0e-6,
            motor_noise_m: 0.3e-3,
            motor_noise_gain: 0.08,
            motor_noise_tau_s: 0.4,
            arm_bandwidth_hz: 4.0,
            lapse_rate_per_h: 6.0,
            lapse_growth_per_10min: 1.0,
            lapse_mean_s: 0.6,
            lapse_min_s: 0.25,
        }
    }
}

/// Between-participant spread of the operator's traits: each trait of
/// participant i is its default times a factor drawn once from (study seed,
/// i). Log-normal factors exp(σ z), z ~ N(0, 1), have median 1; uniform ones
/// are U(lo, hi). Sources in `docs/STUDY.md` §13.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TraitSpread {
    /// Movement speeds (approach, circling, blind, retreat): U(lo, hi).
    pub speed: (f64, f64),
    /// Motor noise floor ("skill"): log-normal σ.
    pub motor_noise_ln_sd: f64,
    /// Force goal ("push lightly" as each person understands it): log-normal σ.
    pub force_goal_ln_sd: f64,
    /// Force-servo gain (force control): log-normal σ.
    pub force_gain_ln_sd: f64,
    /// Force detection threshold: log-normal σ.
    pub force_threshold_ln_sd: f64,
    /// Vibrotactile detection threshold: log-normal σ.
    pub vibration_threshold_ln_sd: f64,
    /// Visual push gain: U(lo, hi).
    pub visual_gain: (f64, f64),
    /// Visuomotor delay, s: U(lo, hi) (absolute, not a factor).
    pub visual_delay_s: (f64, f64),
    /// Haptic (long-latency) delay, s: U(lo, hi) (absolute, not a factor).
    pub haptic_delay_s: (f64, f64),
    /// Attention-lapse rate (`lapse_rate_per_h`): log-normal σ (default
    /// 0.98: the between-person coefficient of variation of rested lapse
    /// rates, ≈ 1.3, `docs/STUDY.md` §13).
    pub lapse_rate_ln_sd: f64,
}

impl Default for TraitSpread {
    fn default() -> Self {
        Self {
            speed: (0.75, 1.25),
            motor_noise_ln_sd: 0.35,
            force_goal_ln_sd: 0.35,
            force_gain_ln_sd: 0.3,
            force_threshold_ln_sd: 0.45,
            vibration_threshold_ln_sd: 0.46,
            visual_gain: (0.8, 1.25),
            visual_delay_s: (0.12, 0.20),
            haptic_delay_s: (0.05, 0.10),
            lapse_rate_ln_sd: 0.98,
        }
    }
}

impl OperatorParams {
    /// The lapse process of an operator with these parameters
    /// ([`crate::lapse`]).
    pub fn lapse_model(&self) -> LapseModel {
        LapseModel {
            rate0_per_s: self.lapse_rate_per_h / 3600.0,
            growth: self.lapse_growth_per_10min,
            min_s: self.lapse_min_s,
            mean_s: self.lapse_mean_s,
        }
    }

    /// Parameters of participant `index` of a study: the defaults with
    /// individual differences ([`TraitSpread::default`]) drawn from (study
    /// seed, participant) only — never from the condition or the trial — so
    /// every trial of a participant uses the same person.
    pub fn for_participant(study_seed: u64, index: u32) -> Self {
        Self::for_participant_with(study_seed, index, &TraitSpread::default())
    }

    /// [`OperatorParams::for_participant`] with a given spread.
    pub fn for_participant_with(study_seed: u64, index: u32, spread: &TraitSpread) -> Self {
        let mut g = SplitMix64::new(splitmix64_mix(study_seed ^ TRAIT_DOMAIN) ^ u64::from(index));
        let mut u = || (g.next_u64() >> 11) as f64 / (1_u64 << 53) as f64;
        let d = Self::default();
        let uniform = |u: f64, (lo, hi): (f64, f64)| lo + (hi - lo) * u;
        let speed = uniform(u(), spread.speed);
        let vision = uniform(u(), spread.visual_gain);
        let visual_delay_s = uniform(u(), spread.visual_delay_s);
        // Box–Muller from two uniforms; u1 in (0, 1].
        let mut ln_factor = |sd: f64| {
            let u1 = 1.0 - u();
            let u2 = u();
            (sd * (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()).exp()
        };
        let noise = ln_factor(spread.motor_noise_ln_sd);
        let force = ln_factor(spread.force_goal_ln_sd);
        let gain = ln_factor(spread.force_gain_ln_sd);
        let threshold = ln_factor(spread.force_threshold_ln_sd);
        let vibration = ln_factor(spread.vibration_threshold_ln_sd);
        // Drawn after the traits above, so adding them left those unchanged.
        let lapses = ln_factor(spread.lapse_rate_ln_sd);
        let haptic_delay_s = uniform(u(), spread.haptic_delay_s);
        Self {
            approach_speed_m_s: d.approach_speed_m_s * speed,
            circling_speed_m_s: d.circling_speed_m_s * speed,
            blind_speed_m_s: d.blind_speed_m_s * speed,
            retreat_speed_m_s: d.retreat_speed_m_s * speed,
            motor_noise_m: d.motor_noise_m * noise,
            force_goal_n: d.force_goal_n * force,
            force_gain_m_per_n_s: d.force_gain_m_per_n_s * gain,
            force_threshold_n: d.force_threshold_n * threshold,
            pacinian: PacinianCurve {
                threshold_m_s2: d.pacinian.threshold_m_s2 * vibration,
                ..d.pacinian
            },
            visual_gain: d.visual_gain * vision,
            visual_delay_s,
            haptic_delay_s,
            lapse_rate_per_h: d.lapse_rate_per_h * lapses,
            ..d
        }
    }
}

/// Vibration percept: a transient (collision spike).
const VIB_TRANSIENT: u8 = 1;
/// Vibration percept: the felt agitation is quiet (dropped on contact).
const VIB_QUIET: u8 = 2;
/// Vibration percept: the agitation came back (contact lost).
const VIB_RESUMED: u8 = 4;

/// Fixed-capacity delay line of percepts sampled at the control rate.
#[derive(Debug, Clone)]
struct Delay<T: Copy> {
    buf: Vec<T>,
    head: usize,
}

impl<T: Copy> Delay<T> {
    fn new(len: usize, fill: T) -> Self {
        Self {
            buf: vec![fill; len.max(1)],
            head: 0,
        }
    }
    fn fill(&mut self, v: T) {
        self.buf.iter_mut().for_each(|x| *x = v);
        self.head = 0;
    }
    /// Pushes `v`, returns the value pushed `len` calls ago.
    fn push(&mut self, v: T) -> T {
        let out = self.buf[self.head];
        self.buf[self.head] = v;
        self.head = (self.head + 1) % self.buf.len();
        out
    }
}

/// Phases of the operator's plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Plan {
    /// Circling: not yet oriented (no frame perceived).
    Waiting,
    /// Circling: approaching / going around.
    Circling,
    /// Blind: moving along the heading.
    Moving,
    /// Blind: retreating.
    Retreating,
}

/// The seeded simulated operator (module docs).
#[derive(Debug, Clone)]
pub struct SimOperator {
    p: OperatorParams,
    rng: ChaCha20Rng,
    lapse_rng: ChaCha20Rng,
    task: TaskKind,
    mapping: HandMapping,
    // Perception.
    force_lp: [f64; 2],
    force_delay: Delay<[f64; 2]>,
    vib_weight: [Sos; 2],
    env_short: f64,
    env_long: f64,
    env_agitation: f64,
    free_agitation: f64,
    quiet: bool,
    vib_delay: Delay<u8>,
    last_vib_event_s: f64,
    last_resume_s: f64,
    force_gain_err: f64,
    frames: [Option<VisualFrame>; 16],
    percept_frame: Option<VisualFrame>,
    seen_noise: [[f64; 2]; 3],
    // Plan.
    plan: Plan,
    centre: [f64; 2],
    contact_r: f64,
    depth: f64,
    theta: f64,
    direction: f64,
    last_used_frame: u64,
    point: [f64; 2],
    heading: [f64; 2],
    retreat_dir: [f64; 2],
    retreated: f64,
    retreat_distance: f64,
    // Motor.
    noise: [f64; 2],
    arm_pos: [f64; 2],
    arm_vel: [f64; 2],
    prev_target: [f64; 2],
    started: bool,
    // Attention lapses.
    lapses: LapseSchedule,
    in_lapse: bool,
}

impl SimOperator {
    /// An operator with `params`; `control_rate_hz` is the rate of `act`
    /// calls and `sample_rate_hz` the rig's (for the filters).
    ///
    /// # Errors
    /// Filter design failure (band outside (0, Nyquist)).
    pub fn new(
        params: OperatorParams,
        control_rate_hz: f64,
        sample_rate_hz: f64,
    ) -> Result<Self, kilotouch_dsp::DspError> {
        let weight = || Sos::new(params.pacinian.sections(sample_rate_hz)?);
        let ticks = |s: f64| ((s * control_rate_hz).round() as usize).max(1);
        let mapping = HandMapping {
            scale: 1.0,
            handle_origin_m: [0.0; 2],
            trap_offset_m: [0.0; 2],
            trap_min_m: [f64::NEG_INFINITY; 2],
            trap_max_m: [f64::INFINITY; 2],
            force_scale: 1.0,
        };
        Ok(Self {
            p: params,
            rng: ChaCha20Rng::from_seed([0; 32]),
            lapse_rng: ChaCha20Rng::from_seed([0; 32]),
            task: TaskKind::Circling,
            mapping,
            force_lp: [0.0; 2],
            force_delay: Delay::new(ticks(params.haptic_delay_s), [0.0; 2]),
            vib_weight: [weight()?, weight()?],
            env_short: 0.0,
            env_long: 0.0,
            env_agitation: 0.0,
            free_agitation: 0.0,
            quiet: false,
            vib_delay: Delay::new(ticks(params.haptic_delay_s), 0),
            last_vib_event_s: f64::NEG_INFINITY,
            last_resume_s: f64::NEG_INFINITY,
            force_gain_err: 1.0,
            frames: [None; 16],
            percept_frame: None,
            seen_noise: [[0.0; 2]; 3],
            plan: Plan::Waiting,
            centre: [0.0; 2],
            contact_r: 0.0,
            depth: 0.0,
            theta: 0.0,
            direction: 1.0,
            last_used_frame: u64::MAX,
            point: [0.0; 2],
            heading: [1.0, 0.0],
            retreat_dir: [-1.0, 0.0],
            retreated: 0.0,
            retreat_distance: 0.0,
            noise: [0.0; 2],
            arm_pos: [0.0; 2],
            arm_vel: [0.0; 2],
            prev_target: [0.0; 2],
            started: false,
            lapses: LapseSchedule::default(),
            in_lapse: false,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &OperatorParams {
        &self.p
    }

    fn gauss(&mut self) -> f64 {
        // Box–Muller; u1 in (0, 1].
        let u1 = 1.0 - unit_uniform(&mut self.rng);
        let u2 = unit_uniform(&mut self.rng);
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    }

    /// Whether the operator is in an attention lapse at `t_s` (s since the
    /// trial start), drawing the lapses up to then from the lapse stream
    /// ([`crate::lapse`]).
    fn lapsing(&mut self, t_s: f64) -> bool {
        self.lapses.lapsing(t_s, &mut self.lapse_rng)
    }

    /// Perceived force vector (delayed, low-passed, gain error), N.
    fn perceive_force(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        let a = 1.0 - (-2.0 * PI * self.p.force_lowpass_hz * obs.dt_s).exp();
        for f in obs.force_n {
            for (lp, &x) in self.force_lp.iter_mut().zip(f) {
                let v = if x.is_finite() { x } else { 0.0 };
                *lp += a * (v - *lp);
            }
        }
        let d = self.force_delay.push(self.force_lp);
        [d[0] * self.force_gain_err, d[1] * self.force_gain_err]
    }

    /// The vibration percepts now (delayed by the haptic delay): a bit set
    /// of [`VIB_TRANSIENT`], [`VIB_QUIET`] and [`VIB_RESUMED`] (module docs).
    fn perceive_vibration(&mut self, obs: &Observation<'_>) -> u8 {
        let a_s = 1.0 - (-obs.dt_s / self.p.vibration_short_s).exp();
        let a_l = 1.0 - (-obs.dt_s / self.p.vibration_long_s).exp();
        let a_a = 1.0 - (-obs.dt_s / self.p.agitation_window_s).exp();
        for acc in obs.accel_m_s2 {
            let mut e = 0.0;
            for (w, &x) in self.vib_weight.iter_mut().zip(acc) {
                let v = if x.is_finite() { x } else { 0.0 };
                let y = w.process(v);
                e += y * y;
            }
            self.env_short += a_s * (e - self.env_short);
            self.env_long += a_l * (e - self.env_long);
            self.env_agitation += a_a * (e - self.env_agitation);
        }
        let thr = self.p.pacinian.threshold_m_s2;
        let thr2 = thr * thr;
        let r2 = self.p.vibration_change_ratio * self.p.vibration_change_ratio;
        let felt = self.env_short.max(self.env_long) > thr2;
        let change = self.env_short > r2 * self.env_long;
        // Ignore the first long time constant (baseline not settled).
        let settled = obs.t_s > 2.0 * self.p.vibration_long_s;
        let mut bits = 0;
        if felt && change && settled {
            bits |= VIB_TRANSIENT;
        }
        if settled {
            let dt = obs.dt_s * obs.accel_m_s2.len() as f64;
            bits |= self.agitation_percept(thr2, dt);
        }
        self.vib_delay.push(bits)
    }

    /// The agitation's quieting and resuming (module docs): the free level
    /// is learned (over `vibration_long_s`) while the agitation is felt and
    /// not quiet; quiet below level ÷ ratio², in mean square, and back above
    /// level ÷ ratio (hysteresis); `dt` is the time since the last call, s.
    /// Returns [`VIB_QUIET`] while quiet and
    /// [`VIB_RESUMED`] at the step it ends.
    fn agitation_percept(&mut self, thr2: f64, dt: f64) -> u8 {
        let r2 = self.p.agitation_drop_ratio * self.p.agitation_drop_ratio;
        let e = self.env_agitation;
        let known = self.free_agitation > thr2;
        let mut bits = 0;
        if self.quiet {
            if e > self.free_agitation / self.p.agitation_drop_ratio {
                self.quiet = false;
                bits |= VIB_RESUMED;
            }
        } else if known && e * r2 < self.free_agitation {
            self.quiet = true;
        }
        if !self.quiet && e > thr2 {
            // Up over the long envelope's time, down ten times slower, so
            // a gradual approach does not teach a lower free level.
            let tau = if e > self.free_agitation { 1.0 } else { 10.0 } * self.p.vibration_long_s;
            self.free_agitation += (1.0 - (-dt / tau).exp()) * (e - self.free_agitation);
        }
        if self.quiet {
            bits |= VIB_QUIET;
        }
        bits
    }

    /// The frame perceived now (displayed at least `visual_delay_s` ago).
    fn perceive_frame(&mut self, obs: &Observation<'_>) {
        if let Some(f) = obs.frame {
            let slot = (f.seq % self.frames.len() as u64) as usize;
            if self.frames[slot].is_none_or(|g| g.seq != f.seq) {
                self.frames[slot] = Some(f);
            }
        }
        let mut best: Option<VisualFrame> = None;
        for f in self.frames.iter().flatten() {
            // Displayed at (roughly) the first act after capture + latency;
            // the runner delivers it then, so the capture time bounds it.
            if f.captured_s + self.p.visual_delay_s <= obs.t_s && best.is_none_or(|b| f.seq > b.seq)
            {
                best = Some(*f);
            }
        }
        if let Some(f) = best
            && self.percept_frame.is_none_or(|g| g.seq != f.seq)
        {
            for k in 0..3 {
                self.seen_noise[k] = [
                    self.p.visual_noise_m * self.gauss(),
                    self.p.visual_noise_m * self.gauss(),
                ];
            }
            self.percept_frame = Some(f);
        }
    }

    fn motor(&mut self, target_trap: [f64; 2], dt: f64) -> [f64; 2] {
        let target = self.mapping.to_hand(target_trap);
        if !self.started {
            self.arm_pos = target;
            self.prev_target = target;
            self.started = true;
        }
        let v = norm([
            (target[0] - self.prev_target[0]) / dt,
            (target[1] - self.prev_target[1]) / dt,
        ]);
        self.prev_target = target;
        let sd = self.p.motor_noise_m + self.p.motor_noise_gain * v;
        let tau = self.p.motor_noise_tau_s;
        let c = (-dt / tau).exp();
        let s = sd * (1.0 - c * c).sqrt();
        for i in 0..2 {
            let g = self.gauss();
            self.noise[i] = c * self.noise[i] + s * g;
        }
        let w = 2.0 * PI * self.p.arm_bandwidth_hz;
        for (i, &t) in target.iter().enumerate() {
            let goal = t + self.noise[i];
            // Critically damped: x'' = w²(goal − x) − 2w x' (semi-implicit Euler).
            let acc = w * w * (goal - self.arm_pos[i]) - 2.0 * w * self.arm_vel[i];
            self.arm_vel[i] += acc * dt;
            self.arm_pos[i] += self.arm_vel[i] * dt;
        }
        self.arm_pos
    }

    fn circling(&mut self, force: [f64; 2], vib_recent: bool, resumed: bool, dt: f64) -> [f64; 2] {
        let fmag = norm(force);
        let felt = fmag > self.p.force_threshold_n;
        let Some(f) = self.percept_frame else {
            // Nothing seen yet: hold still.
            return self.point;
        };
        let c = [
            f.obstacle_m[0] + self.seen_noise[2][0],
            f.obstacle_m[1] + self.seen_noise[2][1],
        ];
        let b = [
            f.bead_m[0] + self.seen_noise[0][0],
            f.bead_m[1] + self.seen_noise[0][1],
        ];
        let t = [
            f.trap_m[0] + self.seen_noise[1][0],
            f.trap_m[1] + self.seen_noise[1][1],
        ];
        let rc = f.obstacle_radius_m + f.bead_radius_m;
        let rb = norm([b[0] - c[0], b[1] - c[1]]);
        let rt = norm([t[0] - c[0], t[1] - c[1]]);
        let seen_gap = rb - rc;
        let seen_touch = seen_gap < self.p.visual_contact_gap_m;
        if self.plan == Plan::Waiting {
            self.plan = Plan::Circling;
            self.centre = c;
            self.contact_r = rc;
            self.theta = (b[1] - c[1]).atan2(b[0] - c[0]);
            self.depth = seen_gap;
            self.direction = if unit_uniform(&mut self.rng) < 0.5 {
                1.0
            } else {
                -1.0
            };
        }
        // The agitation resuming is fresher than the delayed image.
        let touch = felt || vib_recent || (seen_touch && !resumed);
        if !touch {
            self.depth -= self.p.approach_speed_m_s * dt;
        } else {
            if felt {
                self.depth += self.p.force_gain_m_per_n_s * (fmag - self.p.force_goal_n) * dt;
            }
            if seen_touch && f.seq != self.last_used_frame {
                let push = rb - rt;
                self.depth += self.p.visual_gain * (push - self.p.visual_push_goal_m);
            }
            self.theta += self.direction * self.p.circling_speed_m_s / self.contact_r * dt;
        }
        self.last_used_frame = f.seq;
        self.depth = self.depth.clamp(-3.0e-6, 5.0e-6);
        let r = self.contact_r + self.depth;
        [
            self.centre[0] + r * self.theta.cos(),
            self.centre[1] + r * self.theta.sin(),
        ]
    }

    fn blind(&mut self, force: [f64; 2], vib_recent: bool, dt: f64) -> [f64; 2] {
        let fmag = norm(force);
        let felt = fmag > self.p.force_threshold_n;
        match self.plan {
            Plan::Moving | Plan::Waiting | Plan::Circling => {
                if felt || vib_recent {
                    self.plan = Plan::Retreating;
                    let dir = if felt {
                        // The felt force pushes the hand away from the
                        // obstacle: along the outward normal.
                        let sd = self.p.force_direction_sd_deg.to_radians();
                        let a = force[1].atan2(force[0]) + sd * self.gauss();
                        [a.cos(), a.sin()]
                    } else {
                        [-self.heading[0], -self.heading[1]]
                    };
                    self.retreat_dir = dir;
                    self.retreated = 0.0;
                } else {
                    self.point[0] += self.heading[0] * self.p.blind_speed_m_s * dt;
                    self.point[1] += self.heading[1] * self.p.blind_speed_m_s * dt;
                }
            }
            Plan::Retreating => {
                if felt {
                    // Keep moving away from what pushes: along the felt
                    // force (the outward normal).
                    let a = force[1].atan2(force[0]);
                    self.retreat_dir = [a.cos(), a.sin()];
                }
                let step = self.p.retreat_speed_m_s * dt;
                self.point[0] += self.retreat_dir[0] * step;
                self.point[1] += self.retreat_dir[1] * step;
                self.retreated += step;
                // Retreated twice the instructed distance and the trial
                // goes on: it was a false alarm; search on along the heading.
                if self.retreated > 2.0 * self.retreat_distance {
                    self.plan = Plan::Moving;
                    self.retreated = 0.0;
                    self.last_vib_event_s = f64::NEG_INFINITY;
                }
            }
        }
        self.point
    }
}

impl Participant for SimOperator {
    fn begin_trial(&mut self, brief: &TrialBrief) {
        self.rng = brief.rng.clone();
        // Lapses come from their own stream of the trial's generator, so
        // the rest of the trial draws the same numbers with or without them.
        self.lapse_rng = brief.rng.clone();
        self.lapse_rng.set_stream(STREAM_LAPSE);
        self.task = brief.task;
        self.mapping = brief.mapping;
        self.force_lp = [0.0; 2];
        self.force_delay.fill([0.0; 2]);
        for h in &mut self.vib_weight {
            h.reset();
        }
        self.env_short = 0.0;
        self.env_long = 0.0;
        self.env_agitation = 0.0;
        self.free_agitation = 0.0;
        self.quiet = false;
        self.vib_delay.fill(0);
        self.last_vib_event_s = f64::NEG_INFINITY;
        self.last_resume_s = f64::NEG_INFINITY;
        self.force_gain_err = (1.0 + self.p.force_weber * self.gauss()).max(0.2);
        self.frames = [None; 16];
        self.percept_frame = None;
        self.plan = match brief.task {
            TaskKind::Circling => Plan::Waiting,
            TaskKind::BlindNavigation => Plan::Moving,
        };
        self.point = brief.start_trap_m;
        self.heading = brief.heading;
        self.retreat_dir = [-brief.heading[0], -brief.heading[1]];
        self.retreated = 0.0;
        self.retreat_distance = brief.retreat_distance_m;
        self.last_used_frame = u64::MAX;
        self.depth = 0.0;
        self.noise = [0.0; 2];
        self.arm_vel = [0.0; 2];
        self.started = false;
        self.in_lapse = false;
        self.lapses.begin(
            self.p.lapse_model(),
            brief.time_on_task_s,
            &mut self.lapse_rng,
        );
    }

    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        let dt = (obs.force_n.len().max(1) as f64) * obs.dt_s;
        let force = self.perceive_force(obs);
        let vib = self.perceive_vibration(obs);
        if vib & VIB_TRANSIENT != 0 {
            self.last_vib_event_s = obs.t_s;
        }
        if vib & VIB_RESUMED != 0 {
            self.last_resume_s = obs.t_s;
        }
        // Contact felt through vibration: a recent transient, or quiet.
        let vib_recent =
            vib & VIB_QUIET != 0 || obs.t_s - self.last_vib_event_s <= self.p.vibration_memory_s;
        let resumed = obs.t_s - self.last_resume_s <= self.p.vibration_memory_s;
        self.perceive_frame(obs);
        // During a lapse the hand holds still: the plan's trap point stays
        // where it was and resumes from there (module docs).
        self.in_lapse = self.lapsing(obs.t_s);
        let target = if self.in_lapse {
            self.point
        } else {
            match self.task {
                TaskKind::Circling => self.circling(force, vib_recent, resumed, dt),
                TaskKind::BlindNavigation => self.blind(force, vib_recent, dt),
            }
        };
        self.point = target;
        let hand = self.motor(target, dt);
        if hand.iter().all(|v| v.is_finite()) {
            hand
        } else {
            obs.handle_m
        }
    }
}

/// How long the simulated operator takes for one trial of `task` at its
/// default speeds, s: circling, the approach over the start gap and the
/// revolutions around the obstacle; blind navigation, the start gap and
/// the retreat.
pub fn nominal_trial_s(task: &Task) -> f64 {
    let p = OperatorParams::default();
    match task {
        Task::Circling(t) => {
            let r = (t.obstacle_radius_um + t.bead_radius_um) * UM;
            CIRCLING_START_GAP_M / p.approach_speed_m_s
                + t.revolutions * 2.0 * PI * r / p.circling_speed_m_s
        }
        Task::BlindNavigation(t) => {
            t.start_distance_um * UM / p.blind_speed_m_s
                + t.retreat_distance_um * UM / p.retreat_speed_m_s
        }
    }
}

/// The nominal time on task at the start of trial `key` of `protocol`, s:
/// the trials before it in its block (a run of trials with the same
/// participant, phase and condition, begun after a break or instructions,
/// [`crate::screens::gate`]) times a nominal trial ([`nominal_trial_s`])
/// plus the inter-trial interval. The first trial of a block is at 0.
pub fn nominal_time_on_task_s(protocol: &Protocol, key: TrialKey) -> f64 {
    let before = f64::from(key.trial.saturating_sub(1));
    before * (nominal_trial_s(&protocol.task) + protocol.screens.iti_s.max(0.0))
}

/// Angle (degrees) between a retreat direction and a normal; re-exported
/// for tests of the operator's direction perception.
pub fn direction_error_deg(dir: [f64; 2], normal: [f64; 2]) -> f64 {
    angle_between(dir, normal).to_degrees()
}

/// Simulated participants of a study: the [`SimOperator`] of the trial's
/// participant ([`OperatorParams::for_participant`]), rebuilt when the
/// participant changes. Every trial resets the operator's state, so a trial
/// behaves the same whatever ran before it.
#[derive(Debug, Clone)]
pub struct SimCohort {
    study_seed: u64,
    control_rate_hz: f64,
    sample_rate_hz: f64,
    current: Option<(u32, SimOperator)>,
    failed: Option<String>,
}

impl SimCohort {
    /// A cohort for study seed `study_seed`, with `act` called at
    /// `control_rate_hz` on a rig running at `sample_rate_hz`.
    pub fn new(study_seed: u64, control_rate_hz: f64, sample_rate_hz: f64) -> Self {
        Self {
            study_seed,
            control_rate_hz,
            sample_rate_hz,
            current: None,
            failed: None,
        }
    }

    /// Why the last operator could not be built (invalid filter band for
    /// this sample rate), if so; the hand then stays still.
    pub fn error(&self) -> Option<&str> {
        self.failed.as_deref()
    }

    /// The current operator.
    pub fn operator(&self) -> Option<&SimOperator> {
        self.current.as_ref().map(|(_, o)| o)
    }

    /// Build participant `index`'s operator now (it allocates its delay
    /// lines), so that its first trial's `begin_trial` does not: for a
    /// real-time sitting of that one participant.
    pub fn prepare(&mut self, index: u32) {
        if self.current.as_ref().is_some_and(|(p, _)| *p == index) {
            return;
        }
        let params = OperatorParams::for_participant(self.study_seed, index);
        match SimOperator::new(params, self.control_rate_hz, self.sample_rate_hz) {
            Ok(op) => {
                self.current = Some((index, op));
                self.failed = None;
            }
            Err(e) => {
                self.current = None;
                self.failed = Some(e.to_string());
            }
        }
    }
}

impl Participant for SimCohort {
    fn begin_trial(&mut self, brief: &TrialBrief) {
        self.prepare(brief.participant);
        if let Some((_, op)) = &mut self.current {
            op.begin_trial(brief);
        }
    }

    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        match &mut self.current {
            Some((_, op)) => op.act(obs),
            None => obs.handle_m,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn nominal_time_on_task_restarts_with_each_block() {
        let p = Protocol::paper().unwrap();
        let first = TrialKey::new(0, p.conditions[0], crate::seeds::Phase::Test, 1);
        let fifth = TrialKey { trial: 5, ..first };
        assert_eq!(nominal_time_on_task_s(&p, first), 0.0);
        let tau = nominal_time_on_task_s(&p, fifth);
        assert!(tau > 4.0 * nominal_trial_s(&p.task), "{tau}");
        let m = OperatorParams::default().lapse_model();
        assert!(m.rate_per_s(tau) > m.rate_per_s(0.0));
        let next_block = TrialKey {
            condition: p.conditions[1],
            ..first
        };
        assert_eq!(nominal_time_on_task_s(&p, next_block), 0.0);
    }

    const FS: f64 = 10_000.0;
    const PER_ACT: usize = 10;

    /// White Gaussian noise in x and y whose Pacinian-weighted RMS (the
    /// envelope the operator compares with its threshold) is `felt_rms`.
    struct Noise {
        g: SplitMix64,
        scale: f64,
    }

    impl Noise {
        fn new(seed: u64) -> Self {
            // Weighted RMS of unit white noise, measured through the curve.
            let mut n = Self {
                g: SplitMix64::new(seed),
                scale: 1.0,
            };
            let curve = PacinianCurve::default();
            let mut w = Sos::new(curve.sections(FS).unwrap()).unwrap();
            let mut ms = 0.0;
            let k = 200_000;
            for i in 0..k {
                let y = w.process(n.gauss());
                if i >= 10_000 {
                    ms += y * y;
                }
            }
            n.scale = 1.0 / (ms / f64::from(k - 10_000)).sqrt();
            n
        }
        fn gauss(&mut self) -> f64 {
            let u1 = 1.0 - (self.g.next_u64() >> 11) as f64 / (1_u64 << 53) as f64;
            let u2 = (self.g.next_u64() >> 11) as f64 / (1_u64 << 53) as f64;
            (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
        }
        /// Per-axis samples so that both axes together have weighted RMS
        /// `felt_rms` (e = a_x² + a_y²).
        fn sample(&mut self, felt_rms: f64) -> [f64; 3] {
            let s = self.scale * felt_rms / 2.0_f64.sqrt();
            [s * self.gauss(), s * self.gauss(), 0.0]
        }
    }

    /// Runs the vibration percept over `segments` (duration s, weighted RMS
    /// m/s²) and returns (time, bits) per act call.
    fn percepts(params: OperatorParams, segments: &[(f64, f64)], seed: u64) -> Vec<(f64, u8)> {
        let mut op = SimOperator::new(params, FS / PER_ACT as f64, FS).unwrap();
        let mut noise = Noise::new(seed);
        let force = [[0.0; 2]; PER_ACT];
        let mut accel = [[0.0; 3]; PER_ACT];
        let mut out = Vec::new();
        let mut k = 0_u64;
        for &(dur, level) in segments {
            let n = (dur * FS) as usize / PER_ACT;
            for _ in 0..n {
                for a in &mut accel {
                    *a = noise.sample(level);
                }
                k += PER_ACT as u64;
                let obs = Observation {
                    t_s: k as f64 / FS,
                    dt_s: 1.0 / FS,
                    frame: None,
                    force_n: &force,
                    accel_m_s2: &accel,
                    handle_m: [0.0; 2],
                };
                out.push((obs.t_s, op.perceive_vibration(&obs)));
            }
        }
        out
    }

    #[test]
    fn felt_agitation_that_drops_is_perceived_as_quiet_then_as_resuming() {
        let p = OperatorParams::default();
        let thr = p.pacinian.threshold_m_s2;
        let free = 3.0 * thr;
        let v = percepts(p, &[(3.0, free), (2.0, free / 4.0), (2.0, free)], 3);
        let quiet = |a: f64, b: f64| {
            v.iter()
                .filter(|(t, _)| (a..b).contains(t))
                .map(|(_, bits)| bits & VIB_QUIET != 0)
                .collect::<Vec<_>>()
        };
        assert!(quiet(1.0, 3.0).iter().all(|q| !q), "quiet while free");
        // Quiet once the 0.05 s envelope has fallen below free/ratio² in
        // mean square (≈ 0.06 s for a 16× drop in mean square) plus the
        // haptic delay (60 ms), with margin.
        assert!(
            quiet(3.25, 5.0).iter().all(|q| *q),
            "not quiet while pressed"
        );
        assert!(
            quiet(5.3, 7.0).iter().all(|q| !q),
            "still quiet when free again"
        );
        let resumed: Vec<f64> = v
            .iter()
            .filter(|(_, b)| b & VIB_RESUMED != 0)
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(resumed.len(), 1, "{resumed:?}");
        assert!((5.0..5.3).contains(&resumed[0]), "{resumed:?}");
    }

    #[test]
    fn agitation_below_threshold_gives_no_cue_and_steady_agitation_no_false_quiet() {
        let p = OperatorParams::default();
        let thr = p.pacinian.threshold_m_s2;
        let below = percepts(p, &[(3.0, 0.6 * thr), (2.0, 0.1 * thr)], 4);
        assert!(
            below
                .iter()
                .all(|(_, b)| b & (VIB_QUIET | VIB_RESUMED) == 0)
        );
        let steady = percepts(p, &[(20.0, 2.0 * thr)], 5);
        assert!(
            steady
                .iter()
                .all(|(_, b)| b & (VIB_QUIET | VIB_RESUMED) == 0)
        );
    }
}

#[cfg(test)]
mod lapse_tests {
    #![allow(clippy::unwrap_used)]

    use rand_chacha::rand_core::SeedableRng;

    use super::*;

    /// Drives an operator with frequent lapses through `steps` control
    /// periods of 1 ms (no force, no vibration; `frame` shown throughout)
    /// and checks that the plan's trap point holds still while a lapse is
    /// under way, moves otherwise, and resumes from where it stopped.
    /// Returns (steps lapsing, steps acting).
    fn hold_still(task: TaskKind, frame: Option<VisualFrame>, step_m: Option<f64>) -> (u32, u32) {
        let params = OperatorParams {
            lapse_rate_per_h: 1800.0,
            lapse_growth_per_10min: 0.0,
            ..OperatorParams::default()
        };
        let (fs, every) = (10_000.0, 10_usize);
        let mut op = SimOperator::new(params, fs / every as f64, fs).unwrap();
        let mapping = op.mapping;
        op.begin_trial(&TrialBrief {
            participant: 0,
            task,
            mapping,
            start_trap_m: [0.0; 2],
            heading: [1.0, 0.0],
            retreat_distance_m: 3.0e-6,
            rng: ChaCha20Rng::seed_from_u64(17),
            time_on_task_s: 0.0,
        });
        let force = vec![[0.0; 2]; every];
        let accel = vec![[0.0; 3]; every];
        let (mut lapsing, mut acting) = (0, 0);
        let mut prev: Option<(bool, [f64; 2])> = None;
        for k in 0..6000_u32 {
            let obs = Observation {
                t_s: f64::from(k) * 1e-3,
                dt_s: 1.0 / fs,
                frame,
                force_n: &force,
                accel_m_s2: &accel,
                handle_m: [0.0; 2],
            };
            op.act(&obs);
            let now = (op.in_lapse, op.point);
            if let Some((was, before)) = prev {
                let moved = norm([now.1[0] - before[0], now.1[1] - before[1]]);
                if now.0 {
                    lapsing += 1;
                    assert_eq!(now.1, before, "moved during a lapse at step {k}");
                } else {
                    acting += 1;
                    assert!(moved > 0.0, "still while acting at step {k}");
                    if let Some(step) = step_m {
                        // Resumes from the held point: one ordinary step.
                        assert!((moved - step).abs() < 1e-6 * step, "{moved} at {k} ({was})");
                    }
                }
            }
            prev = Some(now);
        }
        (lapsing, acting)
    }

    #[test]
    fn the_hand_holds_still_during_a_lapse_blind() {
        let step = OperatorParams::default().blind_speed_m_s * 1e-3;
        let (lapsing, acting) = hold_still(TaskKind::BlindNavigation, None, Some(step));
        assert!(
            lapsing > 200 && acting > 200,
            "{lapsing} lapsing, {acting} acting"
        );
    }

    #[test]
    fn the_hand_holds_still_during_a_lapse_circling() {
        // The obstacle far away: the operator approaches all along.
        let frame = VisualFrame {
            seq: 0,
            captured_s: -1.0,
            bead_m: [0.0; 2],
            trap_m: [0.0; 2],
            obstacle_m: [20.0e-6, 0.0],
            obstacle_radius_m: 5.0e-6,
            bead_radius_m: 1.5e-6,
        };
        let (lapsing, acting) = hold_still(TaskKind::Circling, Some(frame), None);
        assert!(
            lapsing > 200 && acting > 200,
            "{lapsing} lapsing, {acting} acting"
        );
    }
}
