#!/usr/bin/env bash
# The Slurm test of scripts/slurm/simulate-array.sbatch, for real: installs
# Debian's slurm-wlm and munge when missing, starts munged, slurmctld and
# slurmd as a single-node cluster on this machine (private config, spool and
# state under a temporary folder), submits the shard array and the merge job
# that depends on it, and checks that the merged study equals an unsharded
# run of the same study row for row (every column of trials.csv except the
# wall-clock start time and the row CRC that covers it) and in its summaries.
# Stops the daemons it started. Bounded: a small study, every wait has a
# time-out. All traffic stays on the loopback address.
#
#   scripts/slurm/ci-single-node.sh [path/to/kilotouch]
set -euo pipefail
cd "$(dirname "$0")/../.."
bin="$(realpath "${1:-target/debug/kilotouch}")"
[ -x "$bin" ] || { echo "no kilotouch executable at $bin" >&2; exit 1; }
shards=3
args="--protocol blind --participants 5 --seed 11 --no-raw"

if ! command -v slurmctld >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
    [ "$(id -u)" = 0 ] || { echo "slurm-wlm and munge are missing and this is not root" >&2; exit 1; }
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
fi

work="$(mktemp -d /tmp/kilotouch-slurm.XXXXXX)"
chmod 755 "$work"
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    sleep 1
    for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
}
trap cleanup EXIT

# munge: a private key and socket.
mkdir -p "$work/munge"
dd if=/dev/urandom of="$work/munge/munge.key" bs=1024 count=1 status=none
chmod 700 "$work/munge"; chmod 400 "$work/munge/munge.key"
munged --force --key-file="$work/munge/munge.key" --socket="$work/munge/socket" \
    --pid-file="$work/munge/munged.pid" --log-file="$work/munge/munged.log" \
    --seed-file="$work/munge/seed"
pids+=("$(cat "$work/munge/munged.pid")")

host="$(hostname -s)"
cpus="$(nproc)"
mkdir -p "$work/state" "$work/spool" "$work/log"
cat >"$work/slurm.conf" <<CONF
ClusterName=kilotouch-ci
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$work/munge/socket
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
NodeName=$host NodeAddr=127.0.0.1 NodeHostname=$host CPUs=$cpus State=UNKNOWN
PartitionName=ci Nodes=$host Default=YES MaxTime=30 State=UP
CONF
export SLURM_CONF="$work/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 1 50); do
    [ -f "$work/slurmctld.pid" ] && [ -f "$work/slurmd.pid" ] && break
    sleep 0.2
done
pids+=("$(cat "$work/slurmctld.pid")" "$(cat "$work/slurmd.pid")")

echo "== slurm: waiting for the node"
for i in $(seq 1 60); do
    state="$(sinfo -h -n "$host" -o %t 2>/dev/null || true)"
    case "$state" in idle*|mix*|alloc*) break ;; esac
    [ "$i" = 60 ] && { echo "node not up: $state" >&2; cat "$work/log/"*.log >&2; exit 1; }
    sleep 1
done
sinfo

echo "== unsharded reference run"
# shellcheck disable=SC2086
"$bin" study simulate $args --threads 2 --out "$work/unsharded" >/dev/null

echo "== slurm: array of $shards shards, then the merge"
export KT_BIN="$bin" KT_OUT="$work/cluster" KT_ARGS="$args" KT_SHARDS="$shards"
mkdir -p "$KT_OUT"
jid="$(sbatch --parsable --array=1-"$shards" --chdir="$work" \
    --output="$work/log/shard-%a.out" scripts/slurm/simulate-array.sbatch)"
mid="$(sbatch --parsable --dependency=afterok:"$jid" --kill-on-invalid-dep=yes --chdir="$work" \
    --output="$work/log/merge.out" --export=ALL,KT_MERGE=1 scripts/slurm/simulate-array.sbatch)"
echo "array job $jid, merge job $mid"
for i in $(seq 1 300); do
    [ -z "$(squeue -h -j "$jid,$mid" 2>/dev/null)" ] && break
    [ "$i" = 300 ] && { echo "jobs still queued after 300 s" >&2; squeue >&2; exit 1; }
    sleep 1
done
cat "$work/log/merge.out"
[ -f "$KT_OUT/merged/session.json" ] || {
    echo "the merge job wrote no study" >&2
    cat "$work/log/"*.out "$work/log/slurmctld.log" >&2
    exit 1
}

echo "== compare merged with unsharded"
strip() { cut -d, -f1-15,17-21 "$1"; }
diff <(strip "$work/unsharded/trials.csv") <(strip "$KT_OUT/merged/trials.csv")
for f in cells_long.csv cells_wide.csv; do cmp "$work/unsharded/$f" "$KT_OUT/merged/$f"; done
rows="$(($(wc -l <"$work/unsharded/trials.csv") - 1))"
echo "== slurm: merged study of $shards shards equals the unsharded run ($rows rows)"
