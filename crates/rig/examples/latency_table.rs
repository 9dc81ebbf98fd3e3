//! The loop-delay table of docs/theory/coupling-and-stability.md (closed-loop stability, loop
//! delay): P's and D's worst-case margins, the critical values and the
//! largest safe force scale of the default rig at extra loop delays from
//! 0 to 14 ms, and the delays at which D's phase margin falls below the
//! rig file's minimum and at which D turns unstable.
//!
//! `cargo run --release -p kilotouch-rig --example latency_table`
//! (each row is also `kilotouch rig margins --latency-ms X --json`).

use kilotouch_rig::Condition;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::stability::{LoopAnalysis, analyse_with_latency};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg)?;
    let fs = cfg.rig.sample_rate_hz;
    println!(
        "| extra delay | d | P gain / phase margin | D gain / phase margin | D f_c | critical κ | largest safe g | unstable above g |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for ms in [0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 14.0] {
        let r = analyse_with_latency(&cfg, &chain.coefficients, 1e-3 * ms)?;
        let cell = |c: Condition| {
            r.condition(c).map_or(String::from("–"), |m| {
                format!(
                    "{:.1} dB / {:.1}°{}",
                    m.gain_margin_db,
                    m.phase_margin_deg,
                    if m.stable { "" } else { " (unstable)" }
                )
            })
        };
        let fc = r
            .condition(Condition::D)
            .map_or(f64::NAN, |m| m.gain_crossover_hz);
        println!(
            "| {ms} ms | {} | {} | {} | {fc:.2} Hz | {:.1} pN/µm | {:.3e} | {:.3e} |",
            r.latency_samples,
            cell(Condition::P),
            cell(Condition::D),
            kilotouch_rig::units::to_pn_per_um(r.critical_trap_stiffness_n_per_m),
            r.max_force_scale,
            r.critical_force_scale
        );
    }
    // D's worst phase margin and verdict as functions of the whole delay d.
    let (kappa, g) = (cfg.tweezer.stiffness_n_per_m, cfg.coupling.force_scale);
    let d_cases = |d: usize, margins: bool| -> Result<_, Box<dyn std::error::Error>> {
        let a = LoopAnalysis::new(&cfg, &chain.coefficients)?.with_latency(d as f64 / fs)?;
        let rs = a.evaluate(kappa, g, margins)?;
        Ok(rs
            .into_iter()
            .filter(|r| r.case.condition == Condition::D)
            .collect::<Vec<_>>())
    };
    let min_pm = cfg.stability.min_phase_margin_deg;
    let below_min = |d: usize| -> Result<bool, Box<dyn std::error::Error>> {
        Ok(d_cases(d, true)?
            .iter()
            .any(|r| r.margins.is_some_and(|m| m.phase_margin_deg < min_pm)))
    };
    let unstable = |d: usize| -> Result<bool, Box<dyn std::error::Error>> {
        Ok(d_cases(d, false)?.iter().any(|r| !r.stable))
    };
    for (what, pred) in [
        (
            format!("D's phase margin below {min_pm}°"),
            &below_min as &dyn Fn(usize) -> Result<bool, _>,
        ),
        ("D unstable".to_owned(), &unstable),
    ] {
        let (mut lo, mut hi) = (0usize, 300usize);
        if pred(lo)? || !pred(hi)? {
            println!("{what}: not bracketed in 0..=300 samples");
            continue;
        }
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if pred(mid)? {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        println!(
            "{what} from d = {hi} samples ({:.1} ms; d = {lo}: not yet)",
            1e3 * hi as f64 / fs
        );
    }
    Ok(())
}
