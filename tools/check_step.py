#!/usr/bin/env python3
"""Independent check of splineface's STEP export.

Reads a STEP file with steputils (an ISO 10303-21 parser), rebuilds its first
B_SPLINE_SURFACE_WITH_KNOTS with geomdl (NURBS-Python), evaluates it at the (u, v) pairs read as
JSON from stdin and prints the points as JSON. Needs `pip install steputils geomdl`.

Usage: tools/check_step.py FILE.step < params.json
"""
import json
import sys

from geomdl import BSpline
from steputils import p21


def main():
    step = p21.readfile(sys.argv[1])
    schema = step.header["FILE_SCHEMA"].params[0][0]
    if "AUTOMOTIVE_DESIGN" not in schema and "AP242" not in schema:
        sys.exit(f"unexpected schema {schema}")
    entities = {}
    for section in step.data:
        for ref, instance in section.instances.items():
            entities[ref] = instance
    surfaces = [
        inst
        for inst in entities.values()
        if hasattr(inst, "entity") and inst.entity.name == "B_SPLINE_SURFACE_WITH_KNOTS"
    ]
    if len(surfaces) != 1:
        sys.exit(f"{len(surfaces)} B_SPLINE_SURFACE_WITH_KNOTS entities")
    (_, du, dv, grid, _form, _uc, _vc, _si, mu, mv, ku, kv, _spec) = surfaces[0].entity.params

    def point(ref):
        inst = entities[ref]
        assert inst.entity.name == "CARTESIAN_POINT", inst.entity.name
        return [float(c) for c in inst.entity.params[1]]

    def expand(knots, mults):
        return [float(k) for k, m in zip(knots, mults) for _ in range(int(m))]

    surface = BSpline.Surface()
    surface.degree_u = int(du)
    surface.degree_v = int(dv)
    rows = [[point(r) for r in row] for row in grid]
    surface.ctrlpts2d = rows
    surface.knotvector_u = expand(ku, mu)
    surface.knotvector_v = expand(kv, mv)
    params = json.load(sys.stdin)
    print(json.dumps([surface.evaluate_single((u, v)) for u, v in params]))


if __name__ == "__main__":
    main()
