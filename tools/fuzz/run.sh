#!/usr/bin/env bash
# Fuzzes each target until it has run RUNS inputs or SECONDS have passed, whichever comes
# first, starting from the committed seeds, and prints the executions and anything found.
#
#   tools/fuzz/run.sh [SECONDS [RUNS [TARGET...]]]     (defaults: 60 s, no run limit, all)
#   tools/fuzz/run.sh 1800 10000000                    (the hardening issue's bar)
#
# Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`). Crashes land in
# artifacts/TARGET/, logs in logs-TARGET.txt, the grown corpus in corpus-run/TARGET/.
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-60}"
runs="${2:--1}"
shift $(( $# < 2 ? $# : 2 ))
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    targets=(pts landmarks_json vertex_indices obj ply surface_json reference_json shape_predictor photo glb)
fi
cargo +nightly fuzz build --fuzz-dir . >/dev/null
for target in "${targets[@]}"; do
    mkdir -p "corpus-run/$target" "artifacts/$target"
    cp -n corpus/"$target"/* "corpus-run/$target/" 2>/dev/null || true
    start=$(date +%s)
    status=ok
    cargo +nightly fuzz run --fuzz-dir . "$target" "corpus-run/$target" -- \
        -max_total_time="$seconds" -runs="$runs" -print_final_stats=1 -rss_limit_mb=2048 \
        -max_len=65536 -artifact_prefix="artifacts/$target/" > "logs-$target.txt" 2>&1 || status="FOUND SOMETHING (see logs-$target.txt)"
    executed=$(grep -o "stat::number_of_executed_units: [0-9]*" "logs-$target.txt" | tail -n 1 | awk '{print $2}')
    echo "$target: ${executed:-?} executions in $(( $(date +%s) - start )) s, corpus $(ls "corpus-run/$target" | wc -l) inputs: $status"
done
