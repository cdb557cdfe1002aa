"""geomdl (NURBS-Python) on the refinement bench's surface: the peer for knot insertion and
splitting, which scipy does not have. (geomdl 5.4's `degree_operations` returns a surface
unchanged, its degree included, so there is no peer for degree elevation; checked below.)

    pip install geomdl==5.4.0
    python3 tools/peer_refinement.py && cargo bench --bench bspline -- refinement

The surface is `benches/bspline.rs`'s `cubic_surface(64)`: 64 × 64 control points on clamped
uniform cubic knots over [0, 1]², x and y the grid's indices, z in [0, 1) (here random: the
operations' cost does not depend on the values). Each figure is the best of --repeat runs, one
core (geomdl is pure Python). Run the criterion group right after, as above, so that both are
measured in the same spell of this machine (its speed drifts by a fifth between runs).
"""

import argparse
import copy
import random
import time

from geomdl import BSpline, operations


def surface(n):
    s = BSpline.Surface()
    s.degree_u = s.degree_v = 3
    random.seed(1)
    s.ctrlpts_size_u = s.ctrlpts_size_v = n
    s.ctrlpts = [[i, j, random.random()] for i in range(n) for j in range(n)]
    inner = [k / (n - 3) for k in range(1, n - 3)]
    knots = [0.0] * 4 + inner + [1.0] * 4
    s.knotvector_u = list(knots)
    s.knotvector_v = list(knots)
    return s


def best(repeat, call):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    s = surface(64)
    before = s.evaluate_single((0.3, 0.7))

    def insert(times):
        t = copy.deepcopy(s)
        operations.insert_knot(t, [0.4321, None], [times, 0])
        return t

    elevated = operations.degree_operations(copy.deepcopy(s), [1, 0], check_op=False)
    assert elevated.degree_u == 3, "geomdl now elevates a surface's degree: time it here"

    copying = best(args.repeat, lambda: copy.deepcopy(s))
    rows = [
        ("insert one knot in u", lambda: insert(1)),
        ("insert a knot 3 times in u", lambda: insert(3)),
        ("split in u", lambda: operations.split_surface_u(s, param=0.4321)),
    ]
    print(f"geomdl on a 64 x 64 bicubic (best of {args.repeat}; the copy each in-place operation")
    print(f"needs, {copying * 1e3:.1f} ms, is taken off the insertions)")
    for name, call in rows:
        seconds = best(args.repeat, call)
        if name != "split in u":
            seconds -= copying
        print(f"  {name:32s} {seconds * 1e3:10.1f} ms")
    # The insertions ran (one and three control points more a column) and left the surface
    # where it was.
    for (name, call), more in zip(rows[:2], (1, 3)):
        t = call()
        assert t.ctrlpts_size_u == 64 + more, f"{name}: {t.ctrlpts_size_u} rows"
        gap = max(abs(a - b) for a, b in zip(before, t.evaluate_single((0.3, 0.7))))
        assert gap < 1e-9, f"{name}: moved by {gap}"


if __name__ == "__main__":
    main()
