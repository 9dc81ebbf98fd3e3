#!/usr/bin/env python3
"""pylake's time for the calibration that `cargo bench -p kilotouch-rig --bench
trap_calibration` times: a 1e6-sample record (10 s at 100 kHz, Lorentzian x
diode spectrum synthesised in the frequency domain), fit range 100 Hz-40 kHz,
200 points per block; plain (fast sensor), diode and hydrodynamic models.
Prints the median of 7 runs of calculate_power_spectrum + fit_power_spectrum.

With a path argument, times the record the Rust benchmark wrote there
(`KILOTOUCH_TRAP_RECORD=PATH cargo bench -p kilotouch-rig --bench
trap_calibration`: raw little-endian f64), i.e. both tools on the same record.
"""

import math
import sys
import time

import numpy as np
import lumicks.pylake as lk
from lumicks.pylake.force_calibration.detail.power_models import (
    g_diode,
    passive_power_spectrum_model,
)

FS, N = 100_000.0, 1_000_000
rng = np.random.default_rng(5)
f = np.fft.rfftfreq(N, 1 / FS)
p = np.zeros_like(f)
p[1:] = passive_power_spectrum_model(f[1:], 800.0, 0.4) * g_diode(f[1:], 12_000.0, 0.4)
var = p * FS * N / 2
spec = np.sqrt(var / 2) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
spec[0] = 0
spec[-1] = math.sqrt(var[-1]) * rng.standard_normal()
x = np.fft.irfft(spec, n=N)
if len(sys.argv) > 1:
    x = np.fromfile(sys.argv[1], dtype="<f8")
    assert x.size == N, f"{sys.argv[1]}: {x.size} samples, expected {N}"

for name, kw in [
    ("plain_1e6", dict(fast_sensor=True)),
    ("diode_1e6", dict(fast_sensor=False)),
    ("hydro_1e6", dict(fast_sensor=True, hydrodynamically_correct=True)),
]:
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        ps = lk.calculate_power_spectrum(x, sample_rate=FS, fit_range=(100, 40_000),
                                         num_points_per_block=200)
        model = lk.PassiveCalibrationModel(bead_diameter=3.0, viscosity=1.002e-3,
                                           temperature=20.0, **kw)
        fit = lk.fit_power_spectrum(ps, model)
        times.append(time.perf_counter() - t0)
    print(f"{name}: median {1e3 * sorted(times)[3]:.1f} ms "
          f"(fc {fit['fc'].value:.2f} Hz, kappa {fit['kappa'].value * 1e3:.3f} pN/um)")
