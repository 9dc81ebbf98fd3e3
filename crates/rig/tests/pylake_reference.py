#!/usr/bin/env python3
"""Reference values for the trap calibration, from LUMICKS' pylake.

Writes synthetic detector records (volts, little-endian float32, one file per
record) with a known spectrum and the calibration pylake computes from them
with the same settings that `kilotouch tweezer calibrate` takes. The Rust test
`crates/rig/tests/trap_calibration.rs` fits the same records and compares
(f_c, κ and R_d within 1 %).

The records are synthesised in the frequency domain as pylake's own tests do:
every DFT bin an independent complex Gaussian whose periodogram has the model
spectrum as its mean (pylake's model functions), so each record's spectrum is
exactly known.

Usage (from the repository root):
    pip install lumicks.pylake==1.8.0
    python3 crates/rig/tests/pylake_reference.py
"""

import json
import math
import pathlib

import numpy as np
import lumicks.pylake as lk
from lumicks.pylake.force_calibration.detail.power_models import (
    g_diode,
    passive_power_spectrum_model,
)
from lumicks.pylake.force_calibration.detail.hydrodynamics import (
    passive_power_spectrum_model_hydro,
)

OUT = pathlib.Path(__file__).parent / "data" / "trap_psd"
KB = 1.380649e-23
FS = 50_000.0
N = 1 << 16
T_C = 20.0
T_K = T_C + 273.15
ETA = 1.002e-3


def synthesize(psd, seed):
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(N, 1.0 / FS)
    p = np.zeros_like(f)
    p[1:] = psd(f[1:])
    var = p * FS * N / 2.0
    spec = np.sqrt(var / 2.0) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    spec[0] = 0.0
    spec[-1] = math.sqrt(var[-1]) * rng.standard_normal()
    return np.fft.irfft(spec, n=N)


def truth(radius_um, kappa_pn_um, rd_um_per_v, gamma):
    """f_c (Hz) and D (V²/s) of a trap with drag gamma (N·s/m)."""
    kappa = kappa_pn_um * 1e-6
    fc = kappa / (2 * math.pi * gamma)
    d_m2 = KB * T_K / gamma
    d_v2 = d_m2 / (rd_um_per_v * 1e-6) ** 2
    return fc, d_v2


CASES = [
    # name, record, radius µm, κ pN/µm, R_d µm/V, options, seed
    dict(name="plain", record="plain", radius_um=1.5, kappa=80.0, rd=0.6, seed=1,
         fit_range=(100.0, 20_000.0), ppb=100, hydro=False, diode=False, distance_um=None),
    dict(name="faxen", record="faxen", radius_um=1.5, kappa=80.0, rd=0.6, seed=2,
         fit_range=(100.0, 20_000.0), ppb=100, hydro=False, diode=False, distance_um=4.0),
    dict(name="hydro", record="hydro", radius_um=2.25, kappa=300.0, rd=0.4, seed=3,
         fit_range=(100.0, 23_000.0), ppb=120, hydro=True, diode=False, distance_um=10.0,
         rho_sample=997.0, rho_bead=1050.0),
    dict(name="diode", record="diode", radius_um=1.0, kappa=150.0, rd=0.8, seed=4,
         fit_range=(100.0, 23_000.0), ppb=100, hydro=False, diode=True, distance_um=None,
         f_diode=8_000.0, alpha=0.35),
]


def faxen(l_um, r_um):
    s = r_um / l_um
    return 1.0 / (1 - 9 / 16 * s + 1 / 8 * s**3 - 45 / 256 * s**4 - 1 / 16 * s**5)


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    results = {"pylake_version": lk.__version__, "fs_hz": FS, "n_samples": N,
               "temperature_k": T_K, "viscosity_pa_s": ETA, "cases": []}
    for c in CASES:
        r_m = c["radius_um"] * 1e-6
        gamma0 = 6 * math.pi * ETA * r_m
        if c["hydro"]:
            gamma = gamma0  # the hydrodynamic model's f_c and D refer to bulk drag
        elif c["distance_um"] is not None:
            gamma = gamma0 * faxen(c["distance_um"], c["radius_um"])
        else:
            gamma = gamma0
        fc, d = truth(c["radius_um"], c["kappa"], c["rd"], gamma)
        if c["hydro"]:
            def psd(f, fc=fc, d=d, c=c, r_m=r_m, gamma0=gamma0):
                return passive_power_spectrum_model_hydro(
                    f, fc, d, gamma0=gamma0, bead_radius=r_m, rho_sample=c["rho_sample"],
                    rho_bead=c["rho_bead"], distance_to_surface=c["distance_um"] * 1e-6)
        elif c["diode"]:
            def psd(f, fc=fc, d=d, c=c):
                return passive_power_spectrum_model(f, fc, d) * g_diode(f, c["f_diode"], c["alpha"])
        else:
            def psd(f, fc=fc, d=d):
                return passive_power_spectrum_model(f, fc, d)
        x = synthesize(psd, c["seed"]).astype("<f4")
        x.tofile(OUT / f"{c['record']}.f32")
        data = x.astype(np.float64)

        ps = lk.calculate_power_spectrum(data, sample_rate=FS, fit_range=c["fit_range"],
                                         num_points_per_block=c["ppb"])
        model = lk.PassiveCalibrationModel(
            bead_diameter=2 * c["radius_um"], viscosity=ETA, temperature=T_C,
            hydrodynamically_correct=c["hydro"], distance_to_surface=c["distance_um"],
            rho_sample=c.get("rho_sample"), rho_bead=c.get("rho_bead", 1060.0),
            fast_sensor=not c["diode"])
        fit = lk.fit_power_spectrum(ps, model)
        res = {k: float(fit[k].value) for k in
               ["fc", "err_fc", "D", "err_D", "kappa", "err_kappa", "Rd", "err_Rd", "Rf",
                "chi_squared_per_deg", "backing"]}
        if c["diode"]:
            for k in ["f_diode", "alpha", "err_f_diode", "err_alpha"]:
                res[k] = float(fit[k].value)
        # pylake reports κ in pN/nm; kilotouch in pN/µm.
        res["kappa_pn_um"] = res["kappa"] * 1e3
        res["err_kappa_pn_um"] = res["err_kappa"] * 1e3
        entry = dict(c)
        entry["truth"] = {"fc_hz": fc, "diffusion_v2_s": d, "kappa_pn_um": c["kappa"],
                          "rd_um_per_v": c["rd"]}
        entry["pylake"] = res
        results["cases"].append(entry)
        print(c["name"], {k: round(v, 6) for k, v in res.items()}, "truth fc", round(fc, 3))
    (OUT / "pylake_reference.json").write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
