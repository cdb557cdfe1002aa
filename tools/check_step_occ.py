#!/usr/bin/env python3
"""Opens a splineface STEP file with OpenCASCADE (the CAD kernel behind FreeCAD and CadQuery)
and prints what it found as JSON: the faces and edges it built, whether its shape checker
(BRepCheck_Analyzer) finds the shape valid, the faces' area (Gauss integration to a relative
1e-7: OpenCASCADE's default accuracy is far coarser on a trimmed spline) and the bounding box of
its own fine triangulation of the faces (the box of the untriangulated shape is the box of the
trim's parameter rectangle, wider than the face). With a second
argument, an OBJ mesh of the same face (splineface's face.obj), also that mesh's area, for the
trimmed face's area to be compared with the clipped mesh's.

Needs OpenCASCADE's Python bindings: `pip install cadquery-ocp` (a large wheel with VTK; kept
out of the tests for that reason, run by hand).

Usage: tools/check_step_occ.py FILE.step [FACE.obj]
"""
import json
import sys

from OCP.BRepCheck import BRepCheck_Analyzer
from OCP.BRepGProp import BRepGProp
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.Bnd import Bnd_Box
from OCP.BRepBndLib import BRepBndLib
from OCP.GProp import GProp_GProps
from OCP.IFSelect import IFSelect_RetDone
from OCP.STEPControl import STEPControl_Reader
from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
from OCP.TopExp import TopExp_Explorer


def count(shape, kind):
    explorer = TopExp_Explorer(shape, kind)
    n = 0
    while explorer.More():
        n += 1
        explorer.Next()
    return n


def obj_area(path):
    vertices, area = [], 0.0
    with open(path) as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                vertices.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                a, b, c = (vertices[int(p.split("/")[0]) - 1] for p in parts[1:4])
                u = [b[i] - a[i] for i in range(3)]
                v = [c[i] - a[i] for i in range(3)]
                n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
                area += 0.5 * sum(x * x for x in n) ** 0.5
    return area


def main():
    reader = STEPControl_Reader()
    if reader.ReadFile(sys.argv[1]) != IFSelect_RetDone:
        sys.exit(f"OpenCASCADE could not read {sys.argv[1]}")
    reader.TransferRoots()
    shape = reader.OneShape()
    properties = GProp_GProps()
    BRepGProp.SurfaceProperties_s(shape, properties, 1e-7)
    BRepMesh_IncrementalMesh(shape, 0.01, False, 0.1, True)
    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box, True)
    lo = box.CornerMin()
    hi = box.CornerMax()
    result = {
        "faces": count(shape, TopAbs_FACE),
        "edges": count(shape, TopAbs_EDGE),
        "valid": BRepCheck_Analyzer(shape).IsValid(),
        "area": properties.Mass(),
        "box": [[lo.X(), lo.Y(), lo.Z()], [hi.X(), hi.Y(), hi.Z()]],
    }
    if len(sys.argv) > 2:
        result["mesh_area"] = obj_area(sys.argv[2])
    print(json.dumps(result))


if __name__ == "__main__":
    main()
