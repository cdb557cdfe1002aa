#!/usr/bin/env python3
"""Independent check of splineface's STEP export.

Reads a STEP file with steputils (an ISO 10303-21 parser), rebuilds its one
B_SPLINE_SURFACE_WITH_KNOTS with geomdl (NURBS-Python), evaluates it at the (u, v) pairs read as
JSON from stdin and prints {"points": [...], "trim": ...} as JSON. When the file holds a trimmed
face (an ADVANCED_FACE bounded by a SURFACE_CURVE), "trim" gives its two representations checked
against each other: the space curve and the surface at the parameter-space curve, both rebuilt
with geomdl and evaluated at 1001 parameters, their largest distance ("gap"), the parameter-space
curve's signed area (positive: counter-clockwise) and its vertex count; else it is null.
Needs `pip install steputils geomdl`.

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
    points = [surface.evaluate_single((u, v)) for u, v in params]
    print(json.dumps({"points": points, "trim": trim(entities, surface, point, expand)}))


def trim(entities, surface, point, expand):
    """The trimmed face's boundary checked against the surface, or None when untrimmed."""
    faces = [i for i in entities.values() if hasattr(i, "entity") and i.entity.name == "ADVANCED_FACE"]
    if not faces:
        return None
    if len(faces) != 1:
        sys.exit(f"{len(faces)} ADVANCED_FACE entities")
    (_, bounds, _face_surface, _sense) = faces[0].entity.params
    (bound,) = bounds
    loop = entities[entities[bound].entity.params[1]]
    (oriented,) = loop.entity.params[1]
    edge = entities[entities[oriented].entity.params[3]]
    surface_curve = entities[edge.entity.params[3]]
    assert surface_curve.entity.name == "SURFACE_CURVE", surface_curve.entity.name
    (_, space_ref, (pcurve_ref,), _) = surface_curve.entity.params
    definitional = entities[entities[pcurve_ref].entity.params[2]]
    (plane_ref,) = definitional.entity.params[1]

    def curve(ref, dimension):
        entity = entities[ref].entity
        assert entity.name == "B_SPLINE_CURVE_WITH_KNOTS", entity.name
        (_, degree, refs, _form, _closed, _si, mults, knots, _spec) = entity.params
        c = BSpline.Curve()
        c.degree = int(degree)
        c.ctrlpts = [point(r)[:dimension] for r in refs]
        kv = expand(knots, mults)
        c.knotvector = [k / kv[-1] for k in kv]
        return c

    space = curve(space_ref, 3)
    plane = curve(plane_ref, 2)
    gap = 0.0
    for i in range(1001):
        t = i / 1000
        a = space.evaluate_single(t)
        u, v = plane.evaluate_single(t)
        b = surface.evaluate_single((min(max(u, 0.0), 1.0), min(max(v, 0.0), 1.0)))
        gap = max(gap, sum((x - y) ** 2 for x, y in zip(a, b)) ** 0.5)
    uv = plane.ctrlpts
    area = 0.5 * sum(p[0] * q[1] - p[1] * q[0] for p, q in zip(uv, uv[1:]))
    return {"gap": gap, "area": area, "vertices": len(uv) - 1}


if __name__ == "__main__":
    main()
