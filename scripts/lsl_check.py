#!/usr/bin/env python3
"""Check kilotouch's Lab Streaming Layer outlets with pylsl.

Runs one real-time sitting (`kilotouch study run --lsl` on the simulated
rig), resolves both streams, records them until the sitting ends and checks:

* every trial's `trial_start` and `trial_end` markers arrive, in order, each
  end after its start, in the order and with the keys of `trials.csv`;
* `sitting_start` comes first and `sitting_end` last;
* the signal stream's sample count within each trial matches its nominal
  rate times the trial's marker-to-marker duration within 1 %;
* the signal stream's values are the trial's raw file decimated: for each
  trial the samples between its markers equal (as float32) every n-th row
  of its NPY file (n = the rig's rate / the stream's rate) at one phase, on
  the channels both carry (handle, Pantograph x command, Haptuator drive,
  accelerometer, bead, trap), for
  at least 99 % of them (a sample at a block edge may fall outside);
* the study folder records the LSL clock (`lsl_clock.json`).

Usage: lsl_check.py KILOTOUCH_BINARY PROTOCOL OUT_DIR [RATE_HZ]
"""

import csv
import json
import os
import subprocess
import sys
import time

import numpy as np
import pylsl

# LSL signal channel -> raw NPY column (docs/STUDY.md, standard layout).
# Not compared: force_y (the file keeps x's Pantograph command only) and
# contact (the stream's is the tweezer's contact flag, the file's the task's
# gap < contact_gap).
SHARED = {0: 0, 1: 1, 2: 10, 4: 11, 5: 12, 6: 13, 7: 14, 8: 4, 9: 5, 10: 2, 11: 3}


def fail(msg):
    print(f"lsl_check: FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def resolve(name, timeout):
    found = pylsl.resolve_byprop("name", name, timeout=timeout)
    if not found:
        fail(f"stream {name} not resolved within {timeout} s")
    return found[0]


def parse_marker(text):
    parts = text.split(" ")
    fields = dict(p.split("=", 1) for p in parts[1:] if "=" in p)
    return parts[0], fields


def main():
    if len(sys.argv) < 4:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    binary, protocol, out = sys.argv[1], sys.argv[2], sys.argv[3]
    rate = float(sys.argv[4]) if len(sys.argv) > 4 else 1000.0
    cmd = [
        binary, "study", "run", "--protocol", protocol, "--participant", "P01",
        "--out", out, "--lsl", "--lsl-rate-hz", str(rate),
        "--lsl-wait-s", "30", "--timeout-s", "300", "--json",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE)
    try:
        m_info = resolve("kilotouch-markers", 30)
        s_info = resolve("kilotouch-signals", 30)
        if s_info.channel_count() != 13 or s_info.channel_format() != pylsl.cf_float32:
            fail(f"signal stream: {s_info.channel_count()} channels, format {s_info.channel_format()}")
        srate = s_info.nominal_srate()
        if abs(srate - rate) > 1e-6 * rate:
            fail(f"signal stream nominal rate {srate} Hz, asked for {rate} Hz")
        m_in = pylsl.StreamInlet(m_info, max_buflen=360)
        s_in = pylsl.StreamInlet(s_info, max_buflen=360)
        # Full meta-data (channel labels) from the outlet.
        full = s_in.info(timeout=10)
        ch = full.desc().child("channels").child("channel")
        labels = []
        while not ch.empty():
            labels.append(ch.child_value("label"))
            ch = ch.next_sibling()
        if len(labels) != 13 or labels[0] != "handle_x":
            fail(f"signal channel labels: {labels}")
        study = full.desc().child_value("study")
        participant = full.desc().child_value("participant")
        if participant != "P01" or not study:
            fail(f"meta-data: study={study!r} participant={participant!r}")
        m_in.open_stream(timeout=10)
        s_in.open_stream(timeout=10)
        markers, marker_ts, stamps, values = [], [], [], []
        n_ended = None
        while True:
            chunk, ts = m_in.pull_chunk(timeout=0.0)
            markers += [c[0] for c in chunk]
            marker_ts += ts
            sch, sts = s_in.pull_chunk(timeout=0.0, max_samples=100000)
            stamps += sts
            values += sch
            if proc.poll() is not None:
                if n_ended is None:
                    n_ended = time.monotonic()
                elif time.monotonic() - n_ended > 1.5:
                    break
            time.sleep(0.02)
        stdout = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    if proc.returncode != 0:
        fail(f"study run exited {proc.returncode}")
    report = json.loads(stdout)
    print(f"lsl_check: sitting {report.get('finish')} with {len(markers)} markers, "
          f"{len(stamps)} signal samples at {srate} Hz")
    if not markers or not markers[0].startswith("sitting_start"):
        fail(f"first marker {markers[:1]}, expected sitting_start")
    if not markers[-1].startswith("sitting_end"):
        fail(f"last marker {markers[-1:]}, expected sitting_end")
    with open(os.path.join(out, "trials.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    want = [(r["participant"], r["condition"], r["phase"], r["trial"]) for r in rows]
    trials, open_trial = [], None
    for text, t in zip(markers, marker_ts):
        kind, fld = parse_marker(text)
        if kind == "trial_start":
            if open_trial is not None:
                fail(f"trial_start while {open_trial} runs")
            open_trial = ((fld["participant"], fld["condition"], fld["phase"], fld["trial"]), t)
        elif kind == "trial_end":
            key = (fld["participant"], fld["condition"], fld["phase"], fld["trial"])
            if open_trial is None or open_trial[0] != key:
                fail(f"trial_end {key} without its start ({open_trial})")
            if t < open_trial[1]:
                fail(f"trial_end {key} before its start")
            trials.append((key, open_trial[1], t))
            open_trial = None
    got = [k for k, _, _ in trials]
    if got != want:
        fail(f"trial markers {got} != trials.csv {want}")
    total_expected = 0.0
    total_got = 0
    for key, t0, t1 in trials:
        n = sum(1 for s in stamps if t0 <= s <= t1)
        total_expected += (t1 - t0) * srate
        total_got += n
    if total_expected <= 0 or abs(total_got - total_expected) > 0.01 * total_expected:
        fail(f"signal samples within trials {total_got}, expected {total_expected:.0f} (±1 %)")
    print(f"lsl_check: {len(trials)} trials in order; signal samples within trials "
          f"{total_got} vs {total_expected:.0f} expected "
          f"({100 * (total_got / total_expected - 1):+.2f} %)")
    check_values(out, rows, trials, stamps, values, srate)
    with open(os.path.join(out, "lsl_clock.json")) as f:
        clock = json.load(f)
    if not clock or clock[-1]["participant"] != "P01" or clock[-1]["dropped"] != 0:
        fail(f"lsl_clock.json: {clock}")
    print("lsl_check: OK")


def check_values(out, rows, trials, stamps, values, srate):
    """The stream's samples within each trial are its raw file decimated."""
    stamps = np.asarray(stamps)
    values = np.asarray(values, dtype=np.float32)
    matched = total = 0
    for row, (key, t0, t1) in zip(rows, trials):
        if not row.get("raw_file"):
            fail(f"trial {key} has no raw file")
        path = os.path.join(out, row["raw_file"])
        raw = np.load(path).astype(np.float32)
        with open(path[:-4] + ".json") as f:
            every = round(json.load(f)["sample_rate_hz"] / srate)
        got = values[(stamps >= t0) & (stamps <= t1)]
        if len(got) == 0:
            fail(f"no signal samples within trial {key}")
        lsl_cols = list(SHARED)
        raw_cols = [SHARED[c] for c in lsl_cols]
        best = 0
        for phase in range(every):
            dec = raw[phase::every][:, raw_cols]
            # The stream may start a sample before or after the file.
            for shift in range(-2, 3):
                a = got[max(0, -shift):, :][:, lsl_cols]
                b = dec[max(0, shift):, :]
                n = min(len(a), len(b))
                best = max(best, int(np.sum(np.all(a[:n] == b[:n], axis=1))))
        matched += best
        total += len(got)
        if best < 0.99 * len(got):
            fail(f"trial {key}: {best} of {len(got)} stream samples equal the raw file decimated by {every}")
    print(f"lsl_check: signal values equal the raw files decimated in {matched} of {total} samples")


if __name__ == "__main__":
    main()
