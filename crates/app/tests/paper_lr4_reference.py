"""Reference values for `kilotouch paper`'s Fig. 4 (crates/app/tests/paper_cli.rs):
the fourth-order Linkwitz-Riley crossover of the as-designed chain
(f_c = 200 Hz, f_s = 10 kHz) built independently from scipy.signal's
Butterworth design, squared: L = B_lp(2)^2, H = B_hp(2)^2 (digital,
bilinear transform prewarped at f_c, as scipy.signal.butter does), on the
figure's grid of 401 log-spaced frequencies from 10 Hz to 4 kHz.

Run from the repository root:  python3 crates/app/tests/paper_lr4_reference.py
Writes crates/app/tests/data/paper_fig4_lr4_reference.csv (f_hz,low_db,high_db,sum_db).
"""
import numpy as np
import scipy
from scipy import signal

FS = 10_000.0
FC = 200.0
F = 10.0 * (4000.0 / 10.0) ** (np.arange(401) / 400.0)

lp = signal.butter(2, FC, btype="low", fs=FS, output="sos")
hp = signal.butter(2, FC, btype="high", fs=FS, output="sos")
_, hl = signal.sosfreqz(lp, worN=F, fs=FS)
_, hh = signal.sosfreqz(hp, worN=F, fs=FS)
low = hl * hl
high = hh * hh
with open("crates/app/tests/data/paper_fig4_lr4_reference.csv", "w") as f:
    f.write(f"# scipy {scipy.__version__}: LR4 = Butterworth(2)^2, fc = {FC} Hz, fs = {FS} Hz\n")
    f.write("f_hz,low_db,high_db,sum_db\n")
    for fi, l, h in zip(F, low, high):
        f.write(f"{float(fi)!r},{float(20*np.log10(abs(l)))!r},{float(20*np.log10(abs(h)))!r},{float(20*np.log10(abs(l+h)))!r}\n")
