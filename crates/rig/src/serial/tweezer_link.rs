//! Live tweezer link: [`LinkTweezer`] ([`Tweezer`] over the serial framing)
//! and the instrument behind `kilotouch emulate tweezer`
//! ([`TweezerInstrument`], backed by [`SimTweezer`]).
//!
//! Per loop sample the host sends a TRAP frame (sequence number, trap
//! centre x, y in m as f64) and waits for the TWEEZER_SAMPLES frame of the
//! same sequence number (bead centre x, y in m as f64, detector sum in V as
//! f32, status bits). The optical force is computed on the host from the
//! instrument's stiffness announced in the handshake, F = κ(trap − bead)
//! (paper §4.1, eq. 4), zero while the bead is not trapped. A live
//! instrument does not know the obstacles of a scene, so
//! [`TweezerSample::gap_m`] is +∞ (unknown); contact comes from the status
//! bits.
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

use super::emulator::Instrument;
use super::frame::{
    self, Caps, DeviceKind, Hello, TrapCommand, TweezerCaps, TweezerWireSample,
    tweezer_status as ts,
};
use super::rig::{Link, LinkErrorKind, LinkStats, SerialConfig};
use crate::config::RigConfig;
use crate::error::RigError;
use crate::tweezer::{
    AppliedTrap, DetectedTweezer, SimTweezer, Tweezer, TweezerEvents, TweezerParams, TweezerSample,
};

/// The simulated tweezer as a protocol instrument.
#[derive(Debug)]
pub struct TweezerInstrument {
    tw: DetectedTweezer,
    fs: u32,
    name: String,
    waist_m: f64,
}

impl TweezerInstrument {
    /// The tweezer of `cfg` at the rig's sample rate.
    pub fn new(cfg: &RigConfig) -> Result<Self, RigError> {
        let fs = cfg.rig.sample_rate_hz;
        if fs.fract() != 0.0 || !(1.0..=f64::from(u32::MAX)).contains(&fs) {
            return Err(RigError::InvalidParameter {
                name: "sample_rate_hz",
                value: fs,
                reason: "the serial protocol carries whole Hz".into(),
            });
        }
        let p = TweezerParams::from_config(&cfg.tweezer);
        let waist_m = p.escape_distance_m;
        Ok(Self {
            tw: DetectedTweezer::new(p, &cfg.tweezer.detector, fs)?,
            fs: fs as u32,
            name: format!("{} (tweezer)", cfg.rig.name),
            waist_m,
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
}

/// A live tweezer on a serial link (module docs). `step` blocks for one
/// round trip; on a link failure it returns the last bead position with
/// `trapped = false` and counts the failure ([`LinkTweezer::failures`]).
#[derive(Debug)]
pub struct LinkTweezer {
    link: Link,
    fs: f64,
    kappa: f64,
    announced_kappa: f64,
    seq: u64,
    running: bool,
    last: TweezerSample,
    last_v: [f64; 2],
    calibration: Option<AppliedTrap>,
    failures: u64,
    last_error: Option<LinkErrorKind>,
}

impl LinkTweezer {
    /// Open the port, handshake with a tweezer and start it.
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
        let seq = link.start()?;
        Ok(Self {
            link,
            fs: f64::from(h.sample_rate_hz),
            kappa: c.stiffness_n_per_m,
            announced_kappa: c.stiffness_n_per_m,
            seq,
            running: true,
            last: TweezerSample {
                gap_m: f64::INFINITY,
                trapped: true,
                ..TweezerSample::default()
            },
            last_v: [0.0; 2],
            calibration: None,
            failures: 0,
            last_error: None,
        })
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

    /// The obstacles the instrument reports, in its frame (none yet: the
    /// link does not carry the scene).
    pub fn obstacles(&self) -> &[crate::tweezer::Obstacle] {
        &[]
    }

    /// The instrument's handshake answer.
    pub fn hello(&self) -> &Hello {
        self.link.hello()
    }

    /// The link's configuration (port, options).
    pub fn link_config(&self) -> &SerialConfig {
        self.link.config()
    }

    /// Bead centre of the last sample, m.
    pub fn bead(&self) -> [f64; 2] {
        self.last.bead_m
    }

    /// Stop the instrument's stream (trap held where it is); [`Self::recover`]
    /// starts it again.
    pub fn stop(&mut self) {
        self.link.stop();
        self.running = false;
    }

    /// The calibration in use (None: the instrument's own bead position
    /// and κ).
    pub fn calibration(&self) -> Option<AppliedTrap> {
        self.calibration
    }

    /// Steps that failed (link error, watchdog).
    pub fn failures(&self) -> u64 {
        self.failures
    }

    /// Kind of the last failure.
    pub fn last_error(&self) -> Option<LinkErrorKind> {
        self.last_error
    }

    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }

    /// Restart after a watchdog trip or reopen after a disconnect.
    pub fn recover(&mut self) -> Result<(), RigError> {
        if self.last_error == Some(LinkErrorKind::Disconnected) {
            self.link.reopen(DeviceKind::Tweezer)?;
        }
        self.seq = self.link.start()?;
        self.running = true;
        self.last_error = None;
        Ok(())
    }

    fn failed(&mut self, k: LinkErrorKind, trap: [f64; 2]) -> TweezerSample {
        self.failures += 1;
        self.last_error = Some(k);
        self.running = false;
        if k == LinkErrorKind::Disconnected {
            self.link.stop();
        }
        TweezerSample {
            trap_m: trap,
            force_n: [0.0; 2],
            trapped: false,
            in_contact: false,
            events: TweezerEvents::default(),
            ..self.last
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

    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let trap = if trap_m.iter().all(|v| v.is_finite()) {
            trap_m
        } else {
            self.last.trap_m
        };
        if !self.running {
            return self.failed(self.last_error.unwrap_or(LinkErrorKind::Watchdog), trap);
        }
        let cmd = [TrapCommand { trap_m: trap }];
        let mut got: Option<TweezerWireSample> = None;
        let r = self.link.exchange_items::<TrapCommand, TweezerWireSample>(
            frame::ty::TRAP,
            frame::ty::TWEEZER_SAMPLES,
            &mut self.seq,
            &cmd,
            |_, s| got = s.copied(),
        );
        if let Err(k) = r {
            return self.failed(k, trap);
        }
        self.seq += 1;
        let Some(w) = got else {
            // Lost sample: hold the bead, report no force.
            return TweezerSample {
                trap_m: trap,
                force_n: [0.0; 2],
                events: TweezerEvents::default(),
                ..self.last
            };
        };
        let trapped = w.status & ts::TRAPPED != 0;
        let v = [f64::from(w.detector_v[0]), f64::from(w.detector_v[1])];
        if v.iter().all(|x| x.is_finite()) {
            self.last_v = v;
        }
        let (bead, force) = match self.calibration {
            Some(c) if trapped => c.bead_and_force(trap, self.last_v),
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
        // The device reports no obstacle geometry. Pressed against an
        // obstacle, the contact force balances the optical force, so the
        // bead's displacement from the trap points along the contact normal.
        let d = [bead[0] - trap[0], bead[1] - trap[1]];
        let dn = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let normal = if in_contact && dn > 0.0 && dn.is_finite() {
            [d[0] / dn, d[1] / dn]
        } else {
            [0.0; 2]
        };
        self.last = TweezerSample {
            bead_m: bead,
            trap_m: trap,
            force_n: force,
            gap_m: f64::INFINITY,
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
        };
        self.last
    }

    fn reset(&mut self, trap_m: [f64; 2]) {
        let t = if trap_m.iter().all(|v| v.is_finite()) {
            trap_m
        } else {
            [0.0; 2]
        };
        let c = TrapCommand { trap_m: t };
        frame::write_frame(&mut self.link.tx, frame::ty::RESET, |o| {
            frame::put_item(o, &c)
        });
        if self.link.flush_tx().is_err() {
            self.failed(LinkErrorKind::Disconnected, t);
            return;
        }
        self.last = TweezerSample {
            bead_m: t,
            trap_m: t,
            gap_m: f64::INFINITY,
            trapped: true,
            ..TweezerSample::default()
        };
    }
}
