#!/usr/bin/env python3
"""Where the photo-realistic evaluation's faces lie in front of the truth and where behind it.

Reads the maps `cargo run --release --example photo_eval -- --signed-maps DIR ...` writes (one
per method and set: the score's truth → surface distance over the truth's inner face, mm,
positive where the aligned reconstruction lies in front of the truth, negative behind; a line
"width height", then little-endian f32, NaN outside) and prints,
per subject and per method and photo count, the mean over the sets of

* the RMS of the error over the inner face, and
* the RMS of the sets' *mean* signed map (the part of the error all the sets share), and
* the RMS of the sets' spread about that mean (`√(RMS² − shared²)`),

then writes one picture per subject: the mean face's map and each kind's mean map over the
8- and 16-photo sets (red: the reconstruction in front of the truth, blue: behind, ±3 mm).

When the second figure is nearly the first, the error is not noise the sets average away but a
shape every set of that subject comes to (with the caveat that one subject's sets are drawn from
one pool of photos, so they share its lights and cameras).

Usage: tools/signed_maps.py DIR [OUT_DIR]   (needs numpy and Pillow: pip install numpy pillow)
"""
import collections
import glob
import os
import re
import sys

import numpy as np
from PIL import Image

LIMIT_MM = 3.0


def load(path):
    with open(path, "rb") as f:
        width, height = (int(v) for v in f.readline().split())
        return np.frombuffer(f.read(), dtype="<f4").reshape(height, width)


def picture(values):
    t = np.clip(values / LIMIT_MM, -1.0, 1.0)
    rgb = np.stack(
        [np.where(t > 0, 1.0, 1.0 + t), 1.0 - np.abs(t), np.where(t < 0, 1.0, 1.0 - t)], axis=-1
    )
    rgb = np.nan_to_num(rgb * 255.0, nan=0.0).astype(np.uint8)
    return rgb[::-1]  # the raster's y points up


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__.strip().splitlines()[-1])
    source = sys.argv[1]
    out = sys.argv[2] if len(sys.argv) == 3 else source
    maps = collections.defaultdict(lambda: collections.defaultdict(list))
    for path in sorted(glob.glob(os.path.join(source, "*.bin"))):
        name = os.path.basename(path)[:-4]
        if name.endswith("-mean-face"):
            maps[name[: -len("-mean-face")]]["mean face"].append(load(path))
            continue
        m = re.match(r"(.+?)_(\d+)_photos__seed_\d+-(.+)$", name)
        if m:
            maps[m.group(1)][f"{m.group(3)} {int(m.group(2)):2d}"].append(load(path))
        # the given sets and the halves are left out: they are not drawn like the others
    if not maps:
        sys.exit(f"{source}: no maps (run photo_eval with --signed-maps {source})")
    print("| subject | method, photos | sets | RMS | shared: RMS of the sets' mean | spread |")
    print("|---|---|---|---|---|---|")
    for subject, kinds in maps.items():
        tiles = []
        for kind in sorted(kinds):
            stack = np.stack(kinds[kind])
            mean = np.nanmean(stack, axis=0)
            rms = np.sqrt(np.nanmean(stack**2))
            shared = np.sqrt(np.nanmean(mean**2))
            spread = np.sqrt(max(rms**2 - shared**2, 0.0))
            print(f"| {subject} | {kind.strip()} | {len(stack)} | {rms:.2f} | {shared:.2f} | {spread:.2f} |")
            if kind == "mean face" or kind.endswith((" 8", "16")):
                tiles.append(picture(mean))
        height = max(t.shape[0] for t in tiles)
        canvas = np.full((height, sum(t.shape[1] + 6 for t in tiles), 3), 60, np.uint8)
        x = 0
        for t in tiles:
            canvas[: t.shape[0], x : x + t.shape[1]] = t
            x += t.shape[1] + 6
        Image.fromarray(canvas).save(os.path.join(out, f"signed-{subject}.png"), optimize=True)


if __name__ == "__main__":
    main()
