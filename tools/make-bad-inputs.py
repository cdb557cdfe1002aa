#!/usr/bin/env python3
"""Writes the bad-input corpus, tests/data/bad-inputs/, deterministically.

Every file is made here (the damaged references start from the project's own
reference/ict-mean-face.json); tests/splineface/bad_inputs.rs feeds each one to the command
that reads its kind and checks for a clean failure: exit status 1, a message naming the file and
the problem, no output left behind. A file here without a case there fails that test.

Usage: tools/make-bad-inputs.py   (rewrites the directory)
"""
import json
import os
import shutil
import struct
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "tests", "data", "bad-inputs")


def write(name, data):
    if isinstance(data, str):
        data = data.encode("utf-8")
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(data)


def lcg(seed):
    """The bytes of a small linear congruential generator (no randomness across runs)."""
    state = seed
    while True:
        state = (state * 6364136223846793005 + 1442695040888963407) % (1 << 64)
        yield state >> 56


def noise(n, seed=7):
    g = lcg(seed)
    return bytes(next(g) for _ in range(n))


def png(width, height, pixel):
    """An 8-bit grey PNG; pixel(x, y) -> 0..255."""
    raw = b"".join(b"\x00" + bytes(pixel(x, y) for x in range(width)) for y in range(height))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def pts(points, count=None):
    count = len(points) if count is None else count
    lines = ["version: 1", f"n_points: {count}", "{"] + [f"{x} {y}" for x, y in points] + ["}"]
    return "\n".join(lines) + "\n"


def ibug68():
    """68 plausible points (a rough face outline; only the count and values matter here)."""
    return [(100.0 + 2.0 * k, 120.0 + (k % 17) * 3.0) for k in range(68)]


def landmarks_json(points, scheme="ibug68"):
    return json.dumps({"format": "splineface/landmarks", "version": 1, "scheme": scheme, "points": points})


def dlib_int(value):
    body = abs(value).to_bytes(8, "little").rstrip(b"\x00")
    return bytes([len(body) | (0x80 if value < 0 else 0)]) + body


def main():
    shutil.rmtree(OUT, ignore_errors=True)
    os.makedirs(OUT)
    points = ibug68()

    # Landmark files (.pts).
    write("empty.pts", b"")
    write("truncated.pts", pts(points)[:200])
    write("wrong-count.pts", pts(points[:67], count=68))
    write("nan.pts", pts([(float("nan"), 1.0)] + points[1:]).replace("nan", "NaN"))
    write("inf.pts", pts(points[:5] + [(float("inf"), 1.0)] + points[6:]))
    write("huge-number.pts", pts(points[:9] + [(1e300, 1.0)] + points[10:]).replace("1e+300", "1e400"))
    write("huge-count.pts", pts(points, count=10**12))
    write("negative-count.pts", pts(points, count=-68))
    write("utf16.pts", b"\xff\xfe" + pts(points).encode("utf-16-le"))
    write("latin1.pts", pts(points).replace("version: 1", "version: 1 \u00e9").encode("latin-1"))
    write("binary.pts", noise(700))
    write("12-points.pts", pts(points[:12]))
    write("three-columns.pts", pts(points).replace("100.0 120.0", "100.0 120.0 7.0"))

    # Landmark files (JSON).
    good = [[x, y] for x, y in points]
    write("empty.json", b"")
    write("truncated.json", landmarks_json(good)[:300])
    write("wrong-count.json", landmarks_json(good[:67]))
    write("huge-number.json", landmarks_json(good).replace("100.0", "1e999", 1))
    write("string-numbers.json", json.dumps({"format": "splineface/landmarks", "version": 1,
                                             "scheme": "ibug68", "points": [[str(x), str(y)] for x, y in points]}))
    write("one-coordinate.json", landmarks_json([[x] for x, _ in points]))
    write("mixed-dimensions.json", landmarks_json(good[:67] + [[1.0, 2.0, 3.0]]))
    write("not-an-object.json", "[1, 2, 3]\n")
    write("wrong-format.json", json.dumps({"format": "something/else", "version": 1, "scheme": "ibug68", "points": good}))
    write("unknown-scheme.json", landmarks_json(good, scheme="ibug98"))
    write("utf16.json", b"\xff\xfe" + landmarks_json(good).encode("utf-16-le"))

    # Meshes.
    write("empty.obj", b"")
    write("nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    write("index-out-of-range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
    write("zero-index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    write("no-triangles.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    write("huge-number.obj", "v 0 0 0\nv 1e400 0 0\nv 0 1 0\nf 1 2 3\n")
    write("utf16.obj", b"\xff\xfe" + "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode("utf-16-le"))
    write("binary.obj", noise(500, seed=11))
    ply_header = "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n" \
                 "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    write("truncated.ply", ply_header.format(n=100) + "0 0 0\n" * 10)
    write("huge-count.ply", ply_header.format(n=10**12) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    write("bad-header.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float\nend_header\n")
    write("binary-truncated.ply", ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                                   "property float y\nproperty float z\nend_header\n").encode() + struct.pack("<5f", 0, 0, 0, 1, 0))
    write("empty.glb", b"")
    write("huge-claim.glb", b"glTF" + struct.pack("<II", 2, 3_000_000_000) + struct.pack("<I", 2_999_999_000) + b"JSON{}")
    write("garbage.gltf", "{ this is not json\n")
    buffer_doc = {
        "asset": {"version": "2.0"},
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
    }
    buffer_doc["buffers"][0]["uri"] = "file:///dev/zero"
    write("device-buffer.gltf", json.dumps(buffer_doc))
    buffer_doc["buffers"][0]["uri"] = "missing.bin"
    write("missing-buffer.gltf", json.dumps(buffer_doc))
    buffer_doc["buffers"][0]["uri"] = "https://example.com/mesh.bin"
    write("remote-buffer.gltf", json.dumps(buffer_doc))

    # Reference faces and surfaces, damaged copies of the project's own reference.
    with open(os.path.join(ROOT, "reference", "ict-mean-face.json")) as f:
        reference = json.load(f)
    text = json.dumps(reference)
    write("empty-reference.json", b"")
    write("truncated-reference.json", text[: len(text) // 2])
    damaged = json.loads(text)
    damaged["structure"] = damaged["structure"][:39]
    write("short-structure-reference.json", json.dumps(damaged))
    damaged = json.loads(text)
    damaged["surface"]["control_points"] = damaged["surface"]["control_points"][:-1]
    write("short-grid-reference.json", json.dumps(damaged))
    damaged = json.loads(text)
    damaged["version"] = 99
    write("future-reference.json", json.dumps(damaged))
    surface = reference["surface"]
    surface_text = json.dumps(surface)
    write("empty-surface.json", b"")
    write("truncated-surface.json", surface_text[: len(surface_text) // 3])
    damaged = json.loads(surface_text)
    damaged["knots_u"]["knots"][5], damaged["knots_u"]["knots"][6] = damaged["knots_u"]["knots"][6], damaged["knots_u"]["knots"][5]
    write("decreasing-knots-surface.json", json.dumps(damaged))
    damaged = json.loads(surface_text)
    damaged["knots_v"]["degree"] = 99
    write("degree-99-surface.json", json.dumps(damaged))
    damaged = json.loads(surface_text)
    damaged["rows"] = damaged["rows"] + 1
    write("rows-mismatch-surface.json", json.dumps(damaged))
    write("huge-number-surface.json", surface_text.replace(json.dumps(surface["control_points"][0][0]), "1e999", 1))
    write("utf16-surface.json", b"\xff\xfe" + surface_text.encode("utf-16-le"))

    # dlib landmark models.
    write("empty.dat", b"")
    write("text.dat", "this is not a model\n")
    mean_shape = dlib_int(2) + dlib_int(1) + dlib_int(1) + dlib_int(0) + dlib_int(2) + dlib_int(0)
    write("huge-count.dat", dlib_int(1) + mean_shape + dlib_int(10**12))
    write("wrong-version.dat", dlib_int(7) + mean_shape)
    write("truncated.dat", dlib_int(1) + mean_shape[:5])

    # Photos.
    gradient = png(96, 96, lambda x, y: (x * 2 + y) % 256)
    write("empty.png", b"")
    write("truncated.png", gradient[: len(gradient) // 2])
    write("text.png", "this is not an image\n")
    write("tiny.png", png(8, 8, lambda x, y: 16 * x))
    write("flat.png", png(64, 64, lambda x, y: 128))
    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0)
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    # A well-formed header and an image that is not there: only the header may be read.
    write("huge-header.png", b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
          + chunk(b"IEND", b""))
    write("binary.jpg", b"\xff\xd8\xff\xe0" + noise(2000, seed=3))


if __name__ == "__main__":
    main()
