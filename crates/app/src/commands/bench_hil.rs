//! `kilotouch bench --hil`: does a study run on (emulated) hardware give
//! the simulation's results?
//!
//! The same cohort (the study's seeded operator model) runs the paper's
//! protocol twice: once through `study simulate` (the simulated rig, a loop
//! delay of one sample) and once sitting by sitting through `study run` on
//! the DAQ emulator hosting the participant at its handle (`emulate daq
//! --pty --participant operator:SEED`: the real-time engine, the serial
//! link, a block of 10 samples and a command lead of one block, so 20
//! samples of loop delay). Per condition, the test trials' success rate,
//! time, optical force, displacement error and contact fraction are
//! compared ([`kilotouch_study::stats::agreement`]): within 2.5 pooled
//! standard errors, or the table says which differ.
//!
//! Both watchdogs (the device's and the host's time-out) are 2 s: the
//! benchmark compares results, not fault timing, and must not end on a
//! loaded machine's scheduling.
//!
//! With `--live-tweezer` the tweezer is live too: the tweezer emulator
//! serving the paper's micro-world (`emulate tweezer --pty --protocol
//! paper`) beside the DAQ emulator, exchanging blocks without a command
//! lead, so the loop delay stays 20 samples and any difference comes from
//! the live link and the instrument's frame, not from the margins.
//!
//! The emulator's clock can run faster than real time (`--speed`): the
//! device announces its rig's rate, so the loop delay and every duration in
//! samples are those of the real device; the emulator waits for late
//! commands (its default), so a host that cannot keep up slows the sitting
//! down instead of changing it.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

use anyhow::Context;
use kilotouch_study::export::{TRIALS_FILE, TrialRow, read_trials};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::RunnerConfig;
use kilotouch_study::simulate::{SimulateOptions, simulate};
use kilotouch_study::stats::agreement::{Agreement, Compared, agreement};
use serde::Serialize;

use super::study_run::{RunArgs, sitting};
use crate::session::FinishReason;

/// The agreement bound, pooled standard errors.
pub const BOUND_SE: f64 = 2.5;

/// Settings of the hardware-in-the-loop benchmark.
#[derive(Debug, Clone)]
pub struct HilBench {
    /// Participants (each 10 test trials per condition in the paper's
    /// protocol; 6 give the 60 per condition of the comparison).
    pub participants: usize,
    /// The study seed (the cohort).
    pub seed: u64,
    /// The emulator's clock speed (1 = real time).
    pub speed: f64,
    /// The tweezer live too (its emulator with the paper's micro-world).
    pub live_tweezer: bool,
    /// Where both studies go (kept for inspection).
    pub out: PathBuf,
    /// Simulation threads.
    pub threads: usize,
}

/// `kilotouch bench --hil --json`.
#[derive(Debug, Serialize)]
pub struct HilReport {
    /// Participants per run.
    pub participants: usize,
    /// The study seed.
    pub seed: u64,
    /// The emulator's clock speed.
    pub speed: f64,
    /// The tweezer was live too.
    pub live_tweezer: bool,
    /// Loop delay of the live sittings, samples (block + command lead).
    pub loop_delay_samples: Option<u32>,
    /// The simulated study's folder.
    pub simulated: PathBuf,
    /// The hardware-in-the-loop study's folder.
    pub hil: PathBuf,
    /// Wall time of `study simulate`, s.
    pub simulate_wall_s: f64,
    /// Wall time of the live sittings, s.
    pub hil_wall_s: f64,
    /// Per condition and metric: a = hardware in the loop, b = simulation.
    pub agreement: Vec<Agreement>,
    /// The bound, pooled SE.
    pub bound_se: f64,
    /// Every comparison within the bound.
    pub all_agree: bool,
}

/// A device emulator as a child process (the current executable).
struct Device {
    child: Child,
    path: String,
}

impl Device {
    /// The DAQ emulator with the cohort of study seed `seed` at its handle.
    fn daq(seed: u64, speed: f64) -> anyhow::Result<Self> {
        Self::spawn(
            &["daq", "--participant", &format!("operator:{seed}")],
            speed,
        )
    }

    /// The tweezer emulator serving the paper's micro-world.
    fn tweezer(speed: f64) -> anyhow::Result<Self> {
        Self::spawn(&["tweezer", "--protocol", "paper"], speed)
    }

    fn spawn(args: &[&str], speed: f64) -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("the kilotouch executable")?;
        let mut child = Command::new(exe)
            .arg("emulate")
            .args(&args[..1])
            .arg("--pty")
            .args(&args[1..])
            // Generous watchdogs: the benchmark compares results, not fault
            // timing, and a loaded machine (or real-time throttling of two
            // busy real-time threads on two cores) can hold either side for
            // longer than a firmware's 100 ms.
            .args(["--watchdog-ms", "2000"])
            .arg("--speed")
            .arg(speed.to_string())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting the {} emulator", args[0]))?;
        let mut line = String::new();
        let out = child.stdout.take().context("the emulator's stdout")?;
        BufReader::new(out)
            .read_line(&mut line)
            .context("the emulator's pty path")?;
        let path = line.trim().to_owned();
        if path.is_empty() {
            let _ = child.kill();
            anyhow::bail!("the {} emulator did not print its pty", args[0]);
        }
        Ok(Self { child, path })
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn test_rows(dir: &Path) -> anyhow::Result<Vec<TrialRow>> {
    Ok(read_trials(&dir.join(TRIALS_FILE))?.rows)
}

/// Run both studies and compare them.
pub fn run(b: &HilBench) -> anyhow::Result<HilReport> {
    if b.participants == 0 || b.participants > 64 {
        anyhow::bail!("--participants must be 1 ..= 64, got {}", b.participants);
    }
    let mut protocol = Protocol::paper()?;
    protocol.participants = u32::try_from(b.participants)?;
    protocol.seeds.study = b.seed;
    let sim_dir = b.out.join("simulated");
    let hil_dir = b.out.join("hil");
    for d in [&sim_dir, &hil_dir] {
        if d.exists() {
            anyhow::bail!("{} exists: give --out an empty or new folder", d.display());
        }
    }

    eprintln!(
        "study simulate: {} participant(s), seed {}",
        b.participants, b.seed
    );
    let t0 = Instant::now();
    let opts = SimulateOptions {
        runner: RunnerConfig {
            raw: None,
            ..RunnerConfig::default()
        },
        threads: b.threads.max(1),
        ..SimulateOptions::new(protocol.clone(), &sim_dir)
    };
    simulate(&opts, &mut |_, _| {})?;
    let simulate_wall_s = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let mut loop_delay_samples = None;
    for k in 0..b.participants {
        let id = format!("P{:02}", k + 1);
        eprintln!(
            "hardware in the loop: {id} on the DAQ emulator{} (clock ×{})",
            if b.live_tweezer {
                " and the tweezer emulator"
            } else {
                ""
            },
            b.speed
        );
        let dev = Device::daq(b.seed, b.speed)?;
        let tw = if b.live_tweezer {
            Some(Device::tweezer(b.speed)?)
        } else {
            None
        };
        let args = RunArgs {
            protocol: "paper".into(),
            rig: format!("serial:{},lead=1,timeout-ms=2000", dev.path),
            tweezer: tw.as_ref().map_or_else(
                || "sim".into(),
                |t| format!("serial:{},lead=0,timeout-ms=2000", t.path),
            ),
            trap_calibration: None,
            assume_free_bytes: None,
            participant: id.clone(),
            out: hil_dir.clone(),
            resume: k > 0,
            no_raw: true,
            fast: false,
            timeout_s: 86_400.0,
            loop_args: super::rig::LoopArgs {
                rig_config: None,
                calibration: None,
            },
            json: true,
            #[cfg(feature = "lsl")]
            lsl: false,
            #[cfg(feature = "lsl")]
            lsl_rate_hz: 1000.0,
            #[cfg(feature = "lsl")]
            lsl_wait_s: 0.0,
        };
        let (report, finish) = sitting(&args, (k == 0).then(|| protocol.clone()))?;
        match finish {
            FinishReason::ParticipantDone(_) | FinishReason::StudyDone => {}
            FinishReason::Failed(why) => anyhow::bail!("{id}'s sitting failed: {why}"),
            FinishReason::Stopped => anyhow::bail!("{id}'s sitting was stopped"),
        }
        loop_delay_samples = report.device.map(|d| d.loop_delay_samples);
    }
    let hil_wall_s = t1.elapsed().as_secs_f64();

    let hil = test_rows(&hil_dir)?;
    let sim = test_rows(&sim_dir)?;
    let table = agreement(&hil, &sim, &Compared::CIRCLING, BOUND_SE);
    let all_agree = !table.is_empty() && table.iter().all(|a| a.agrees);
    Ok(HilReport {
        participants: b.participants,
        seed: b.seed,
        speed: b.speed,
        live_tweezer: b.live_tweezer,
        loop_delay_samples,
        simulated: sim_dir,
        hil: hil_dir,
        simulate_wall_s,
        hil_wall_s,
        agreement: table,
        bound_se: BOUND_SE,
        all_agree,
    })
}

impl HilReport {
    /// The table for a terminal (and docs/PERFORMANCE.md).
    pub fn describe(&self) -> String {
        let mut s = format!(
            "hardware in the loop ({} participant(s), seed {}, {}loop delay {} samples, clock ×{}) \
             against study simulate; a = HIL, b = simulation\n\n\
             | condition | metric | n a/b | mean HIL | mean sim | pooled SE | z | within {} SE |\n\
             |---|---|---|---|---|---|---|---|\n",
            self.participants,
            self.seed,
            if self.live_tweezer {
                "live tweezer, "
            } else {
                ""
            },
            self.loop_delay_samples
                .map_or_else(|| "?".into(), |d| d.to_string()),
            self.speed,
            self.bound_se
        );
        for a in &self.agreement {
            s += &format!(
                "| {} | {} | {}/{} | {:.4} | {:.4} | {:.4} | {:+.2} | {} |\n",
                a.condition,
                a.metric,
                a.n_a,
                a.n_b,
                a.mean_a,
                a.mean_b,
                a.pooled_se,
                a.z,
                if a.agrees { "yes" } else { "**no**" }
            );
        }
        s += &format!(
            "\nstudy simulate {:.0} s, the live sittings {:.0} s; {}\n",
            self.simulate_wall_s,
            self.hil_wall_s,
            if self.all_agree {
                "every comparison agrees"
            } else {
                "some comparisons differ"
            }
        );
        s
    }
}
