#!/usr/bin/env bash
# Regenerates reference/ict-mean-face.json, the project's default reference face, from the
# ICT-FaceKit mean face (MIT; see reference/README.md).
#
# Usage: tools/build_reference.sh [ICT_FACE_DIR]
#   ICT_FACE_DIR holds neutral_face.obj and landmarks68.txt (default: ../shared/data/ict-face).
set -euo pipefail
cd "$(dirname "$0")/.."
dir="${1:-../shared/data/ict-face}"
for f in neutral_face.obj landmarks68.txt; do
    [[ -f "$dir/$f" ]] || { echo "error: $dir/$f not found" >&2; exit 1; }
done
cargo run --release --quiet -- fit-reference \
    --mesh "$dir/neutral_face.obj" \
    --landmarks "$dir/landmarks68.txt" \
    --out reference/ict-mean-face.json \
    --note "Fitted to the ICT-FaceKit neutral (mean) face, Copyright (c) 2020 USC Institute for Creative Technologies, MIT licence: see reference/README.md."
