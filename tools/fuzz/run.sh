#!/usr/bin/env bash
# Runs every fuzz target for SECONDS (default 60) from the committed seeds and prints the
# executions and anything found. Needs the nightly toolchain and cargo-fuzz
# (`cargo install cargo-fuzz`). Crashes land in artifacts/TARGET/.
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-60}"
for target in pts landmarks_json obj ply surface_json reference_json shape_predictor photo glb; do
    mkdir -p "corpus-run/$target" "artifacts/$target"
    cp -n corpus/"$target"/* "corpus-run/$target/" 2>/dev/null || true
    cargo +nightly fuzz run --fuzz-dir . "$target" "corpus-run/$target" -- \
        -max_total_time="$seconds" -print_final_stats=1 -rss_limit_mb=2048 -max_len=65536 \
        -artifact_prefix="artifacts/$target/" > "logs-$target.txt" 2>&1 || echo "$target: FOUND SOMETHING (see logs-$target.txt)"
    runs=$(grep -o "stat::number_of_executed_units: [0-9]*" "logs-$target.txt" | tail -n 1 | awk '{print $2}')
    echo "$target: ${runs:-?} executions in ${seconds} s"
done
