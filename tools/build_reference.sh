#!/usr/bin/env bash
# Regenerates reference/ict-mean-face.json, the project's default reference face, from the
# ICT-FaceKit mean face (MIT; see reference/README.md), in two steps:
#
# 1. fit-reference: the control grid, structure, edges and clip region, from the mean face and
#    its 68 landmark vertices;
# 2. tools/photo_eval --calibrate: the photo structure (where the photo path puts a landmarker's
#    points on that face), from photo-realistic renders of it. This step needs dlib's model
#    (../shared/models, or tools/fetch-models) and ../shared/data/{lps-head,dlib-faces}; without
#    them the reference is written without a photo structure (the photo stages then deform
#    from the landmark vertices);
# 3. tools/face_space --write: the face space (ICT-FaceKit's 60 identity modes and 53 expression
#    blendshapes on the grid, as `fit-reference --identity-modes --expression-modes` makes them),
#    from ICT_FACE_DIR's identities.f32, expressions.f32 and expressions.txt.
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
model=../shared/models/shape_predictor_68_face_landmarks.dat
if [[ -f "$model" && -d ../shared/data/lps-head && -d ../shared/data/dlib-faces ]]; then
    # The calibration reads the embedded reference: build the library with the new fit first.
    cargo run --release --quiet --example photo_eval -- --ict "$dir" --model "$model" \
        --calibrate reference/ict-mean-face.json
else
    echo "warning: $model or ../shared/data missing: no photo structure measured" >&2
fi
cargo run --release --quiet --example face_space -- --ict "$dir" --write reference/ict-mean-face.json
