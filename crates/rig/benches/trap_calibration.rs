//! Criterion benchmark of the trap calibration
//! (`cargo bench -p kilotouch-rig --bench trap_calibration`): a record of
//! 10⁶ samples (10 s at 100 kHz, frequency-domain synthesis of a Lorentzian
//! × diode spectrum) calibrated end to end — periodogram, blocking,
//! analytical start, fit, κ and R_d — with the plain, diode and
//! hydrodynamic models. pylake on the same record:
//! `KILOTOUCH_TRAP_RECORD=/tmp/rec.f64 cargo bench … ` writes it (raw
//! little-endian f64), `python3 crates/rig/benches/pylake_timing.py
//! /tmp/rec.f64` times pylake on it. Figures in docs/PERFORMANCE.md.

use criterion::{Criterion, criterion_group, criterion_main};
use kilotouch_dsp::trap_psd::diode_filter;
use kilotouch_dsp::trap_psd::lorentzian_one_sided;
use kilotouch_dsp::trap_psd::synth::synthesize_record;
use kilotouch_rig::normal::NormalStream;
use kilotouch_rig::tweezer::calibration::{TrapCalibrationSettings, calibrate_trap};
use std::hint::black_box;

const N: usize = 1_000_000;
const FS: f64 = 100_000.0;

fn settings(hydro: bool, diode: bool) -> TrapCalibrationSettings {
    TrapCalibrationSettings {
        fs_hz: FS,
        radius_m: 1.5e-6,
        viscosity_pa_s: 1.002e-3,
        temperature_k: 293.15,
        fit_range_hz: (100.0, 40_000.0),
        points_per_block: 200,
        hydro,
        diode,
        aliased: false,
        fluid_density_kg_m3: 997.0,
        bead_density_kg_m3: 1060.0,
        distance_to_surface_m: None,
    }
}

fn bench(c: &mut Criterion) {
    let mut rng = NormalStream::new(5);
    let x = synthesize_record(
        |f| lorentzian_one_sided(f, 800.0, 0.4) * diode_filter(f, 12_000.0, 0.4),
        N,
        FS,
        &mut || rng.sample(),
    )
    .expect("record");
    if let Some(path) = std::env::var_os("KILOTOUCH_TRAP_RECORD") {
        let bytes: Vec<u8> = x.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&path, bytes).expect("writing the record");
    }
    let mut g = c.benchmark_group("trap_calibration");
    g.sample_size(20);
    for (name, hydro, diode) in [
        ("plain_1e6", false, false),
        ("diode_1e6", false, true),
        ("hydro_1e6", true, false),
    ] {
        let s = settings(hydro, diode);
        // What is timed: the fit's iterations and quality.
        let (c, _) = calibrate_trap(&x, &s).expect("calibration");
        eprintln!(
            "{name}: f_c {:.2} ± {:.2} Hz, κ {:.3} pN/µm, χ²/dof {:.3}, {} points, {} iterations",
            c.corner_hz,
            c.corner_se_hz,
            kilotouch_rig::units::to_pn_per_um(c.kappa_n_per_m),
            c.chi2_per_dof,
            c.n_points,
            c.iterations
        );
        g.bench_function(name, |b| {
            b.iter(|| calibrate_trap(black_box(&x), &s).expect("calibration"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
