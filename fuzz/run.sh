#!/usr/bin/env bash
# Coverage-guided fuzzing of the file loaders (protocol and rig TOML,
# trials.csv, the journal, session.json) and of the serial stream decoder
# (kilotouch-proto, any byte sequence) with libFuzzer, for SECONDS each
# (default 60). Usage: fuzz/run.sh [SECONDS]
#
# Runs on the stable toolchain: the targets are built with LLVM's
# SanitizerCoverage passes (-Cpasses=sancov-module and its -Cllvm-args, the
# instrumentation cargo-fuzz uses) but without AddressSanitizer, whose
# -Zsanitizer flag needs a nightly compiler that this project's machines
# cannot fetch. The loaders are safe Rust (the workspace denies
# unsafe_code), so what the fuzzer looks for is panics, overflows
# (overflow-checks and debug-assertions are on) and the targets' own
# assertions (an accepted file must be usable), not memory errors.
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-60}"
host="$(rustc -vV | sed -n 's/^host: //p')"
# --target keeps the instrumentation out of build scripts and proc macros.
export RUSTFLAGS="--cfg fuzzing -Cpasses=sancov-module \
-Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters \
-Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares"
cargo build --release --bins --locked --target "$host"
work="$(mktemp -d)"
for t in protocol_toml rig_toml trials_csv journal_jsonl session_json decoder; do
    mkdir -p "$work/$t"
    echo "== fuzz $t: ${seconds} s (seeds: fuzz/corpus/$t)"
    # The first folder collects the inputs found; the second holds seeds.
    "target/$host/release/$t" -max_total_time="$seconds" -rss_limit_mb=2048 \
        -max_len=65536 -print_final_stats=1 -artifact_prefix="$work/$t-" \
        "$work/$t" $( [ -d "corpus/$t" ] && echo "corpus/$t" ) 2>&1 | grep -E "^(#[0-9]+ +DONE|Done|stat::number_of_executed_units|==|SUMMARY|panicked|thread)" || true
    # A crash leaves its input as an artifact: fail with it.
    if compgen -G "$work/$t-*" >/dev/null; then
        echo "fuzz $t: failing input(s):" "$work/$t"-*
        exit 1
    fi
done
echo "== fuzz: no failure"
