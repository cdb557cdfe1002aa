"""splineface: smooth 3D faces from a handful of uncalibrated photos, and a fast B-spline kernel.

The face::

    import splineface
    face = splineface.reconstruct(photos="photos/", landmark_model="shape_predictor_68_face_landmarks.dat")
    face.vertices, face.triangles, face.uv      # the clipped mesh: (n, 3), (m, 3), (n, 2)
    face.texture, face.depth                    # (side, side, 3) uint8, (h, w) float64
    face.structure, face.poses, face.report     # (40, 3), per-photo poses, report.json as a dict
    face.save("out/")                           # every file `splineface reconstruct` writes

Landmarks, with the model loaded once (pass the Landmarker as ``landmark_model`` too)::

    marker = splineface.Landmarker("shape_predictor_68_face_landmarks.dat")
    faces = marker.detect(image)                # numpy uint8 (h, w, 3): every face, largest first

Photos to try it on without a landmark model (the embedded demo subject, rendered, with its
landmark files)::

    splineface.write_demo_photos("demo/", photos=8)
    face = splineface.reconstruct(photos="demo/", landmarks="demo/")

The kernel::

    surface = splineface.BSplineSurface.fit(points, params, shape=(16, 16))
    surface.eval(params), surface.eval_grid(us, vs), surface.derivatives(params, 2), surface.normal(params)

Many subjects (one folder each), as ``splineface batch`` does, on any executor (a Dask cluster:
``examples/dask_batch.py`` in the repository's ``python/`` folder)::

    rows = [splineface.reconstruct_subject(folder, "out/", landmark_model=marker)
            for folder in splineface.batch_subjects("subjects/", "out/")]
    splineface.write_summary("out/", rows)

Arrays are numpy, float64 (uint8 for images) and C-contiguous; other arrays raise ``TypeError``
or ``ValueError`` naming the argument. Reconstructions, models and files that cannot be used
raise ``SplinefaceError`` with the message the command line gives.
"""

from ._native import (
    BSplineSurface,
    Face,
    Landmarker,
    Reconstruction,
    SplinefaceError,
    __version__,
    batch_subjects,
    reconstruct,
    reconstruct_subject,
    write_demo_photos,
    write_summary,
)

__all__ = [
    "BSplineSurface",
    "Face",
    "Landmarker",
    "Reconstruction",
    "SplinefaceError",
    "__version__",
    "batch_subjects",
    "reconstruct",
    "reconstruct_subject",
    "write_demo_photos",
    "write_summary",
]
