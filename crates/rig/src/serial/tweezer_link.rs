//! Live tweezer link: [`LinkTweezer`] ([`Tweezer`] over the serial framing)
//! and the instrument behind `kilotouch emulate tweezer`
//! ([`TweezerInstrument`], backed by [`SimTweezer`]).
//!
//! **Block exchange with a command lead** (`docs/PROTOCOL.md` §7), as the
//! DAQ link ([`super::lead`]): per block of n samples the host sends the
//! block's trap set-points (TRAP frames: sequence number, trap centre x, y
//! in m as f64) L samples ahead of the samples it waits for, then reads the
//! TWEEZER_SAMPLES of the block (bead centre x, y in m as f64, detector
//! signals in V as f32, status bits). A run's first block sends the lead's
//! L set-points first, all at the trap's reset position. The bead sample
//! `out[i]` of a block is thus the answer to the set-point sent L samples
//! earlier; its optical force is computed on the host with the set-point
//! the device applied at that sample (a ring of the set-points sent, by
//! sequence number; the previous one when the device flags a held
//! set-point), F = κ(trap − bead) (paper §4.1, eq. 4), zero while the bead
//! is not trapped. The link adds its lead of L samples to the loop's
//! delay beyond the block ([`Tweezer::loop_delay_samples`]).
//!
//! **Scene.** After the handshake the host asks for the tweezer's scene
//! (SCENE_REQ → SCENE, §6.5: bead radius, obstacles in the trap's frame)
//! and computes each sample's surface gap and contact normal from it with
//! the simulated tweezer's geometry ([`crate::tweezer::nearest_obstacle`]).
//! A device without a scene answers FAULT `BAD_FRAME`: the gap is then +∞
//! (unknown) and a contact's normal is taken from the bead's displacement.
//!
//! **Failures.** A stall, an end of file, a watchdog trip or an emergency
//! stop ends the run: [`Tweezer::link_error`] names it (until
//! [`LinkTweezer::recover`] or a [`Tweezer::reset`] that restarts the
//! device), and the samples carry no force and no events, the bead's
//! trapped state as last known — a lost link is never reported as an
//! escape. An escape is the device's own status bit.
//!
//! The emulator's detector sum models a quadrant photodiode behind a bead
//! in a Gaussian beam: S = S₀·exp(−|b − t|²/w²) with S₀ = 1 V and w the
//! trap's escape distance (an emulated quantity, for link tests and
//! displays; it is not used by the loop). Its difference signals (x, y)
//! come from the simulated position detector of the rig file
//! ([`crate::tweezer::Detector`]: sensitivity, photodiode filter, noise)
//! fed with the bead's displacement from the trap.
//!
//! **Calibration.** Until [`LinkTweezer::apply_calibration`] the host uses
//! the instrument's bead position and its announced κ. A passive
//! calibration of the detector signals ([`crate::tweezer::calibration`])
//! gives κ and the displacement sensitivity R_d; once applied, the bead is
//! placed at trap + R_d·V and the force is κ_cal (trap − bead).

use super::emulator::{Instrument, wire_rate_hz};
use super::frame::{
    self, Caps, DeviceKind, Hello, MAX_SCENE_OBSTACLES, Scene, SceneObstacle, TrapCommand,
    TweezerCaps, TweezerWireSample, tweezer_status as ts,
};
use super::lead::Pipeline;
use super::rig::{Link, LinkErr, LinkErrorKind, LinkStats, SerialConfig};
use crate::config::RigConfig;
use crate::error::RigError;
use crate::tweezer::{
    AppliedTrap, DetectedTweezer, Obstacle, SimTweezer, Tweezer, TweezerEvents, TweezerParams,
    TweezerSample, nearest_obstacle,
};

/// The simulated tweezer as a protocol instrument.
#[derive(Debug)]
pub struct TweezerInstrument {
    tw: DetectedTweezer,
    fs: u32,
    name: String,
    waist_m: f64,
    scene: Scene,
}

impl TweezerInstrument {
    /// The tweezer of `cfg` at the rig's sample rate.
    pub fn new(cfg: &RigConfig) -> Result<Self, RigError> {
        let fs = wire_rate_hz(cfg.rig.sample_rate_hz)?;
        let p = TweezerParams::from_config(&cfg.tweezer);
        let waist_m = p.escape_distance_m;
        let obstacles: Vec<SceneObstacle> = p
            .obstacles
            .iter()
            .map(|o| SceneObstacle {
                centre_m: o.centre_m,
                radius_m: o.radius_m,
            })
            .collect();
        let scene = Scene::new(p.radius_m, &obstacles).ok_or_else(|| {
            RigError::InvalidInput(format!(
                "the rig file's tweezer has {} obstacles; a tweezer reports at most \
                 {MAX_SCENE_OBSTACLES} in its scene (docs/PROTOCOL.md §6.5)",
                obstacles.len()
            ))
        })?;
        Ok(Self {
            tw: DetectedTweezer::new(p, &cfg.tweezer.detector, f64::from(fs))?,
            fs,
            name: format!("{} (tweezer)", cfg.rig.name),
            waist_m,
            scene,
        })
    }

    /// The simulated tweezer.
    pub fn tweezer(&self) -> &SimTweezer {
        self.tw.tweezer()
    }
}

impl Instrument for TweezerInstrument {
    type Command = TrapCommand;
    type Sample = TweezerWireSample;
    const COMMAND_TYPE: u8 = frame::ty::TRAP;
    const SAMPLE_TYPE: u8 = frame::ty::TWEEZER_SAMPLES;

    fn hello(&self) -> Hello {
        let caps = Caps::Tweezer(TweezerCaps {
            stiffness_n_per_m: self.tw.stiffness_n_per_m(),
        });
        Hello::emulator(self.fs, caps, &self.name, "emulator-0002", "tweezer")
    }

    fn step(&mut self, cmd: &TrapCommand, extra_flags: u8) -> TweezerWireSample {
        let s = self.tw.step(cmd.trap_m);
        let d2 = (s.bead_m[0] - s.trap_m[0]).powi(2) + (s.bead_m[1] - s.trap_m[1]).powi(2);
        let mut status = 0;
        for (on, bit) in [
            (s.trapped, ts::TRAPPED),
            (s.in_contact, ts::IN_CONTACT),
            (s.events.contact_start, ts::CONTACT_START),
            (s.events.contact_end, ts::CONTACT_END),
            (s.events.escaped, ts::ESCAPED),
            (s.events.recaptured, ts::RECAPTURED),
            (extra_flags & frame::flag::CMD_LATE != 0, ts::CMD_LATE),
        ] {
            if on {
                status |= bit;
            }
        }
        if extra_flags & frame::flag::WATCHDOG != 0 {
            status |= ts::WATCHDOG;
        }
        let v = self.tw.detector_v().unwrap_or_default();
        TweezerWireSample {
            bead_m: s.bead_m,
            sum_v: (-d2 / (self.waist_m * self.waist_m)).exp() as f32,
            detector_v: [v[0] as f32, v[1] as f32],
            status,
        }
    }

    fn safe_command(&self, last: &TrapCommand) -> TrapCommand {
        *last
    }

    fn reset(&mut self, cmd: &TrapCommand) {
        self.tw.reset(cmd.trap_m);
    }

    fn scene(&self) -> Option<Scene> {
        Some(self.scene)
    }
}

/// Largest block exchanged at once, samples: a longer `step_block` is
/// exchanged in pieces of this length.
pub const MAX_BLOCK_SAMPLES: usize = 1024;

/// Trap set-points remembered by sequence number (≥ the largest lead plus
/// the largest block).
const SENT_RING: usize = 4096;
const _: () = assert!(super::lead::MAX_LEAD_SAMPLES as usize + MAX_BLOCK_SAMPLES <= SENT_RING);

/// Trap set-points per TRAP frame (16-byte items: a 517-byte payload).
pub const FRAME_TRAPS: usize = 32;

/// A live tweezer on a serial link (module docs). `step_block` exchanges a
/// block in one round trip, pipelined by the command lead of
/// [`SerialConfig::lead`].
#[derive(Debug)]
pub struct LinkTweezer {
    link: Link,
    fs: f64,
    kappa: f64,
    /// κ of the handshake (the force's stiffness without a calibration).
    announced_kappa: f64,
    pipe: Pipeline,
    running: bool,
    /// The trap of the lead's set-points: where it was reset, then the
    /// last set-point sent.
    hold: [f64; 2],
    /// Set-points sent, by sequence number modulo [`SENT_RING`].
    sent: Box<[[f64; 2]]>,
    /// The set-point the device applied at the last sample received.
    applied: [f64; 2],
    last: TweezerSample,
    last_v: [f64; 2],
    calibration: Option<AppliedTrap>,
    scene: Option<LinkScene>,
    failures: u64,
    /// The failure since the last restart ([`Tweezer::link_error`]).
    error: Option<LinkErrorKind>,
    last_error: Option<LinkErrorKind>,
    failure: Option<RigError>,
}

/// The geometry a tweezer reported (SCENE): bead radius and obstacles.
#[derive(Debug, Clone, PartialEq)]
struct LinkScene {
    bead_radius_m: f64,
    obstacles: Vec<Obstacle>,
}

/// How a sample of the device becomes a [`TweezerSample`].
struct Decode<'a> {
    kappa: f64,
    calibration: Option<AppliedTrap>,
    scene: Option<&'a LinkScene>,
}

impl Decode<'_> {
    /// The sample `w` with the set-point `trap` applied; `last_v` holds the
    /// last finite detector signals.
    fn sample(
        &self,
        w: &TweezerWireSample,
        trap: [f64; 2],
        last_v: &mut [f64; 2],
    ) -> TweezerSample {
        let trapped = w.status & ts::TRAPPED != 0;
        let v = [f64::from(w.detector_v[0]), f64::from(w.detector_v[1])];
        if v.iter().all(|x| x.is_finite()) {
            *last_v = v;
        }
        let (bead, force) = match self.calibration {
            Some(c) if trapped => c.bead_and_force(trap, *last_v),
            _ if trapped => (
                w.bead_m,
                [
                    self.kappa * (trap[0] - w.bead_m[0]),
                    self.kappa * (trap[1] - w.bead_m[1]),
                ],
            ),
            _ => (w.bead_m, [0.0; 2]),
        };
        let in_contact = w.status & ts::IN_CONTACT != 0;
        let (gap, normal) = match self.scene {
            Some(sc) => nearest_obstacle(&sc.obstacles, sc.bead_radius_m, bead)
                .map_or((f64::INFINITY, [0.0; 2]), |(_, n, g)| (g, n)),
            // No scene: pressed against an obstacle, the contact force
            // balances the optical force, so the bead's displacement from
            // the trap points along the contact normal.
            None => {
                let d = [bead[0] - trap[0], bead[1] - trap[1]];
                let dn = (d[0] * d[0] + d[1] * d[1]).sqrt();
                let n = if in_contact && dn > 0.0 && dn.is_finite() {
                    [d[0] / dn, d[1] / dn]
                } else {
                    [0.0; 2]
                };
                (f64::INFINITY, n)
            }
        };
        TweezerSample {
            bead_m: bead,
            trap_m: trap,
            force_n: force,
            gap_m: gap,
            normal,
            in_contact,
            trapped,
            events: TweezerEvents {
                contact_start: w.status & ts::CONTACT_START != 0,
                contact_end: w.status & ts::CONTACT_END != 0,
                escaped: w.status & ts::ESCAPED != 0,
                recaptured: w.status & ts::RECAPTURED != 0,
            },
            substeps: 1,
        }
    }
}

/// `t` when finite, else `or`.
fn finite_or(t: [f64; 2], or: [f64; 2]) -> [f64; 2] {
    if t.iter().all(|v| v.is_finite()) {
        t
    } else {
        or
    }
}

/// The kind of a failed (re)start.
fn start_failure(e: &RigError) -> LinkErrorKind {
    match e {
        RigError::Device(m) if m.contains("emergency stop") => LinkErrorKind::EmergencyStop,
        RigError::Device(_) => LinkErrorKind::Watchdog,
        _ => LinkErrorKind::Disconnected,
    }
}

impl LinkTweezer {
    /// Open the port, handshake with a tweezer, read its scene and start
    /// it. The command lead is `cfg.lead` (`serial:PATH,lead=auto|N`).
    pub fn open(cfg: &SerialConfig) -> Result<Self, RigError> {
        let mut link = Link::open(cfg, DeviceKind::Tweezer)?;
        let h = link.hello().clone();
        let Caps::Tweezer(c) = h.caps else {
            return Err(RigError::Device("not a tweezer".into()));
        };
        if !(c.stiffness_n_per_m.is_finite() && c.stiffness_n_per_m > 0.0) {
            return Err(RigError::Device(format!(
                "{}: trap stiffness {} N/m is not finite and > 0",
                cfg.path, c.stiffness_n_per_m
            )));
        }
        let scene = Self::read_scene(&mut link)?;
        let seq = link.start()?;
        let mut tw = Self {
            link,
            fs: f64::from(h.sample_rate_hz),
            kappa: c.stiffness_n_per_m,
            announced_kappa: c.stiffness_n_per_m,
            pipe: Pipeline::start(seq),
            running: true,
            hold: [0.0; 2],
            sent: vec![[0.0; 2]; SENT_RING].into_boxed_slice(),
            applied: [0.0; 2],
            last: TweezerSample::default(),
            last_v: [0.0; 2],
            calibration: None,
            scene,
            failures: 0,
            error: None,
            last_error: None,
            failure: None,
        };
        tw.last = tw.at_rest([0.0; 2]);
        Ok(tw)
    }

    /// Ask the device for its scene (`None`: it has none).
    fn read_scene(link: &mut Link) -> Result<Option<LinkScene>, RigError> {
        let mut buf = [0u8; frame::MAX_PAYLOAD];
        let Some(n) = link.query(frame::ty::SCENE_REQ, frame::ty::SCENE, &mut buf)? else {
            return Ok(None);
        };
        let path = &link.config().path;
        let sc = frame::parse_scene(&buf[..n])
            .ok_or_else(|| RigError::Device(format!("{path}: malformed SCENE from the tweezer")))?;
        let r = sc.bead_radius_m;
        if !(r.is_finite() && r > 0.0 && r < 1e-3) {
            return Err(RigError::Device(format!(
                "{path}: the tweezer announced a bead radius of {r} m, outside (0, 1 mm); \
                 refusing its scene (docs/PROTOCOL.md §6.5)"
            )));
        }
        let mut obstacles = Vec::with_capacity(sc.obstacles().len());
        for (i, o) in sc.obstacles().iter().enumerate() {
            let ok = o.centre_m.iter().all(|v| v.is_finite() && v.abs() < 1.0)
                && o.radius_m.is_finite()
                && o.radius_m > 0.0
                && o.radius_m < 1e-2;
            if !ok {
                return Err(RigError::Device(format!(
                    "{path}: the tweezer's obstacle {i} (centre {:?} m, radius {} m) is not \
                     finite or not within 1 m, radius in (0, 1 cm); refusing its scene \
                     (docs/PROTOCOL.md §6.5)",
                    o.centre_m, o.radius_m
                )));
            }
            obstacles.push(Obstacle {
                centre_m: o.centre_m,
                radius_m: o.radius_m,
            });
        }
        Ok(Some(LinkScene {
            bead_radius_m: r,
            obstacles,
        }))
    }

    /// The bead at rest in the trap at `t`, as a sample.
    fn at_rest(&self, t: [f64; 2]) -> TweezerSample {
        let (gap, normal) = self
            .scene
            .as_ref()
            .and_then(|sc| nearest_obstacle(&sc.obstacles, sc.bead_radius_m, t))
            .map_or((f64::INFINITY, [0.0; 2]), |(_, n, g)| (g, n));
        TweezerSample {
            bead_m: t,
            trap_m: t,
            gap_m: gap,
            normal,
            trapped: true,
            ..TweezerSample::default()
        }
    }

    /// Use a trap calibration from now on: bead = trap + R_d·V and force
    /// κ (trap − bead) ([`AppliedTrap::bead_and_force`]). Non-finite or
    /// non-positive κ, or non-finite R_d, is refused.
    pub fn apply_calibration(&mut self, c: AppliedTrap) -> Result<(), RigError> {
        c.validate()?;
        self.kappa = c.stiffness_n_per_m;
        self.calibration = Some(c);
        Ok(())
    }

    /// Use `c` from now on, or (None) the instrument's own bead position
    /// and announced κ again ([`Self::apply_calibration`]).
    pub fn set_calibration(&mut self, c: Option<AppliedTrap>) -> Result<(), RigError> {
        match c {
            Some(c) => self.apply_calibration(c),
            None => {
                self.kappa = self.announced_kappa;
                self.calibration = None;
                Ok(())
            }
        }
    }

    /// The link's configuration (port, options).
    pub fn link_config(&self) -> &SerialConfig {
        self.link.config()
    }

    /// Bead centre of the last sample, m.
    pub fn bead(&self) -> [f64; 2] {
        self.last.bead_m
    }

    /// Stop the instrument's stream (trap held where it is);
    /// [`Self::recover`] starts it again (a new run).
    pub fn stop(&mut self) {
        self.link.stop();
        self.running = false;
    }

    /// The calibration in use (None: the instrument's own bead position
    /// and κ).
    pub fn calibration(&self) -> Option<AppliedTrap> {
        self.calibration
    }

    /// The device's handshake answer.
    pub fn hello(&self) -> &Hello {
        self.link.hello()
    }

    /// The command lead, samples, for blocks of `n` samples
    /// ([`Link::lead_samples`]).
    pub fn lead_samples(&self, n: usize) -> u64 {
        self.link.lead_samples(n)
    }

    /// The obstacles the tweezer reported in its scene (trap frame, m);
    /// empty when it has none or reports no scene.
    pub fn obstacles(&self) -> &[Obstacle] {
        self.scene.as_ref().map_or(&[], |s| &s.obstacles)
    }

    /// The bead radius of the tweezer's scene, m (`None`: no scene).
    pub fn bead_radius_m(&self) -> Option<f64> {
        self.scene.as_ref().map(|s| s.bead_radius_m)
    }

    /// Samples delivered without the device's answer because the link had
    /// failed (stall, disconnect, watchdog, emergency stop).
    pub fn failures(&self) -> u64 {
        self.failures
    }

    /// Kind of the last failure (kept after a recovery).
    pub fn last_error(&self) -> Option<LinkErrorKind> {
        self.last_error
    }

    /// What the last failure was, naming the port (`None` while none).
    pub fn failure(&self) -> Option<&RigError> {
        self.failure.as_ref()
    }

    /// The last failure, taken out (for an error that wraps it).
    pub fn take_failure(&mut self) -> Option<RigError> {
        self.failure.take()
    }

    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }

    /// Restart after a watchdog trip or reopen after a disconnect (and read
    /// the scene again): a new run, whose lead holds the trap where it
    /// was last sent.
    pub fn recover(&mut self) -> Result<(), RigError> {
        if self.last_error == Some(LinkErrorKind::Disconnected) {
            self.link.reopen(DeviceKind::Tweezer)?;
            self.scene = Self::read_scene(&mut self.link)?;
        }
        let seq = self.link.restart(|_| {})?;
        self.pipe = Pipeline::start(seq);
        self.running = true;
        self.error = None;
        self.failure = None;
        Ok(())
    }

    fn fail(&mut self, e: &LinkErr) {
        let k = e.kind();
        self.fail_with(k, self.link.map_err(e));
    }

    fn fail_with(&mut self, k: LinkErrorKind, e: RigError) {
        self.error = Some(k);
        self.last_error = Some(k);
        self.failure = Some(e);
        self.running = false;
        if k == LinkErrorKind::Disconnected {
            self.link.stop();
        }
    }

    /// Samples of a failed link: no force, no events, the rest as last
    /// known (never an escape).
    fn fill_failed(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        volts: Option<&mut [[f64; 2]]>,
    ) {
        for (t, o) in traps.iter().zip(out.iter_mut()) {
            *o = TweezerSample {
                trap_m: finite_or(*t, self.last.trap_m),
                force_n: [0.0; 2],
                events: TweezerEvents::default(),
                ..self.last
            };
        }
        if let Some(v) = volts {
            v.iter_mut().for_each(|x| *x = self.last_v);
        }
        self.failures += traps.len() as u64;
    }

    /// Queue the set-points of a block (the run's lead first) and send
    /// them; returns the first sample they are for.
    fn send_block(&mut self, traps: &[[f64; 2]]) -> Result<(), LinkErr> {
        let n = traps.len();
        if let Some((first, l)) = self.pipe.open_lead(self.link.lead_samples(n)) {
            let hold = self.hold;
            for q in first..first + l {
                self.sent[(q % SENT_RING as u64) as usize] = hold;
            }
            self.link
                .queue_items(frame::ty::TRAP, first, l as usize, FRAME_TRAPS, |_| {
                    TrapCommand { trap_m: hold }
                });
        }
        let at = self.pipe.queue(n);
        let mut prev = self.hold;
        for (i, t) in traps.iter().enumerate() {
            prev = finite_or(*t, prev);
            self.sent[((at + i as u64) % SENT_RING as u64) as usize] = prev;
        }
        self.hold = prev;
        let sent = &self.sent;
        self.link
            .queue_items(frame::ty::TRAP, at, n, FRAME_TRAPS, |i| TrapCommand {
                trap_m: sent[((at + i as u64) % SENT_RING as u64) as usize],
            });
        self.link
            .flush_tx()
            .map_err(|_| LinkErr::Io(std::io::ErrorKind::BrokenPipe.into()))
    }

    /// One block of at most [`MAX_BLOCK_SAMPLES`] (module docs).
    fn exchange_block(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        mut volts: Option<&mut [[f64; 2]]>,
    ) {
        if !self.running {
            return self.fill_failed(traps, out, volts);
        }
        if let Err(e) = self.send_block(traps) {
            self.fail(&e);
            return self.fill_failed(traps, out, volts);
        }
        let n = traps.len();
        let s = self.pipe.next_seq;
        let dec = Decode {
            kappa: self.kappa,
            calibration: self.calibration,
            scene: self.scene.as_ref(),
        };
        let (sent, applied, last, last_v) = (
            &self.sent,
            &mut self.applied,
            &mut self.last,
            &mut self.last_v,
        );
        let mut done = 0;
        let r =
            self.link
                .exchange::<TweezerWireSample>(frame::ty::TWEEZER_SAMPLES, s, n, |i, w| {
                    let set = sent[((s + i as u64) % SENT_RING as u64) as usize];
                    out[i] = match w {
                        Some(w) => {
                            // A held set-point (late, or the watchdog's): the
                            // device kept the previous one.
                            let held = w.status & (ts::CMD_LATE | ts::WATCHDOG) != 0;
                            *applied = if held { *applied } else { set };
                            *last = dec.sample(w, *applied, last_v);
                            *last
                        }
                        // Lost sample: hold the bead, report no force.
                        None => {
                            *applied = set;
                            TweezerSample {
                                trap_m: set,
                                force_n: [0.0; 2],
                                events: TweezerEvents::default(),
                                ..*last
                            }
                        }
                    };
                    if let Some(v) = volts.as_deref_mut() {
                        v[i] = *last_v;
                    }
                    done = i + 1;
                });
        match r {
            Ok(_) => self.pipe.received(n),
            Err(e) => {
                self.fail(&e);
                let v = volts.map(|v| &mut v[done..]);
                self.fill_failed(&traps[done..], &mut out[done..], v);
            }
        }
    }

    /// [`Tweezer::step_block`] in pieces of at most [`MAX_BLOCK_SAMPLES`].
    fn step_pieces(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        mut volts: Option<&mut [[f64; 2]]>,
    ) {
        let n = traps
            .len()
            .min(out.len())
            .min(volts.as_ref().map_or(usize::MAX, |v| v.len()));
        let mut a = 0;
        while a < n {
            let b = (a + MAX_BLOCK_SAMPLES).min(n);
            let v = volts.as_deref_mut().map(|v| &mut v[a..b]);
            self.exchange_block(&traps[a..b], &mut out[a..b], v);
            a = b;
        }
    }
}

impl Tweezer for LinkTweezer {
    fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    fn stiffness_n_per_m(&self) -> f64 {
        self.kappa
    }

    fn detector_v(&self) -> Option<[f64; 2]> {
        Some(self.last_v)
    }

    /// A block of one.
    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let mut o = [self.last];
        self.step_pieces(&[trap_m], &mut o, None);
        o[0]
    }

    fn step_block(&mut self, traps: &[[f64; 2]], out: &mut [TweezerSample]) {
        self.step_pieces(traps, out, None);
    }

    fn step_block_detected(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        volts: &mut [[f64; 2]],
    ) -> bool {
        self.step_pieces(traps, out, Some(volts));
        true
    }

    /// The command lead (this run's, or the next run's): what the link
    /// adds to the loop beyond the block, which the rig's delay counts.
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        let lead = self.pipe.lead_or(|| self.link.lead_samples(block_len));
        u32::try_from(lead).unwrap_or(u32::MAX)
    }

    fn link_error(&self) -> Option<LinkErrorKind> {
        self.error
    }

    fn round_trip_s(&self) -> Option<f64> {
        self.link.round_trip().map(|d| d.as_secs_f64())
    }

    /// A new run with the trap and the bead at `trap_m`: STOP, RESET, START
    /// (the set-points already sent ahead are dropped with the old run; the
    /// new run's lead holds the trap at `trap_m`). Restarts a tripped
    /// device (clearing [`Tweezer::link_error`]); a lost port needs
    /// [`LinkTweezer::recover`].
    fn reset(&mut self, trap_m: [f64; 2]) {
        let t = finite_or(trap_m, [0.0; 2]);
        self.hold = t;
        self.applied = t;
        self.last = self.at_rest(t);
        if self.error == Some(LinkErrorKind::Disconnected) {
            return;
        }
        let c = TrapCommand { trap_m: t };
        match self
            .link
            .restart(|tx| frame::write_frame(tx, frame::ty::RESET, |o| frame::put_item(o, &c)))
        {
            Ok(seq) => {
                self.pipe = Pipeline::start(seq);
                self.running = true;
                self.error = None;
                self.failure = None;
            }
            Err(e) => self.fail_with(start_failure(&e), e),
        }
    }
}
