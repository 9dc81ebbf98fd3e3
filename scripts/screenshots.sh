#!/usr/bin/env bash
# Regenerates the README's images of the app (docs/screenshots/*.png) under a
# virtual display: `scripts/screenshots.sh [path/to/kilotouch]` from the repo
# root (default binary: target/release/kilotouch, built if missing).
#
# * rig, calibration, explore: the pages as they open;
# * study: the Study page in the middle of a real-time sitting of the
#   simulated participant (paper protocol, P01), participant view inline;
# * results: the Results page on a small simulated study (the paper
#   protocol with 4 participants, `kilotouch study simulate`).
set -euo pipefail
bin="${1:-target/release/kilotouch}"
[ -x "$bin" ] || cargo build --release -p kilotouch
out=docs/screenshots
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
shot() { # page file seconds [extra gui args...]
    local page=$1 file=$2 secs=$3
    shift 3
    timeout 300 xvfb-run -a -s "-screen 0 1280x900x24" \
        "$bin" gui --page "$page" --size 1100x760 --screenshot-bits 5 \
        --screenshot "$out/$file" --quit-after "$secs" "$@"
}
shot rig rig.png 4
shot calibration calibration.png 4
shot explore explore.png 6
shot study study.png 12 --study-dir "$work/sitting" --simulate-sitting
"$bin" study simulate --protocol paper --participants 4 --seed 1 \
    --out "$work/study" --no-raw >/dev/null
shot results results.png 8 --study-dir "$work/study"
echo "screenshots written to $out/"
