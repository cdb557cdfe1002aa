"""reconstruct, Reconstruction and Landmarker from Python: what the command line gives, as arrays."""

import ast
import json
import pathlib

import numpy as np
import pytest

import splineface


@pytest.fixture(scope="module")
def face(demo_photos):
    return splineface.reconstruct(photos=demo_photos, landmarks=demo_photos, refine=False, texture_size=256)


def test_a_reconstruction_gives_its_arrays(face):
    n = face.vertices.shape[0]
    assert face.vertices.shape == (n, 3) and face.vertices.dtype == np.float64 and n > 1000
    assert face.triangles.dtype == np.uint32 and face.triangles.shape[1] == 3
    assert face.triangles.max() < n
    assert face.uv.shape == (n, 2) and 0.0 <= face.uv.min() and face.uv.max() <= 1.0
    assert face.texture.shape == (256, 256, 3) and face.texture.dtype == np.uint8
    assert face.structure.shape == (40, 3)
    assert face.units == "mm"
    # The depth map: NaN around the face, heights in millimetres on it, top row first (the
    # forehead above the chin: the top rows hold the eyes' and forehead's heights).
    depth = face.depth
    assert depth.ndim == 2 and np.isnan(depth).any() and np.isfinite(depth).sum() > 1000
    rows = np.where(np.isfinite(depth).any(axis=1))[0]
    assert rows[0] < depth.shape[0] / 4
    assert len(face.photos_used) == 6
    assert face.photos_skipped == []


def test_the_report_and_poses_are_dicts(face):
    report = face.report
    assert report["format"] == "splineface/report"
    stages = [t["stage"] for t in report["timings"]]
    assert "depth" in stages
    poses = face.poses
    assert len(poses) == 6
    assert {"name", "yaw_degrees", "pitch_degrees", "roll_degrees"} <= set(poses[0])


def test_save_writes_what_the_command_line_writes(face, tmp_path):
    face.save(tmp_path / "out")
    written = sorted(str(p.relative_to(tmp_path / "out")) for p in (tmp_path / "out").rglob("*") if p.is_file())
    assert written == sorted(face.files)
    for name in ["face.obj", "face.glb", "surface.json", "surface.step", "depth.exr", "structure.json",
                 "report.json", "report.html", "face.png"]:
        assert name in written
    # face.obj holds the same vertices (written with 6 decimals).
    obj = (tmp_path / "out" / "face.obj").read_text().splitlines()
    vertices = np.array([[float(x) for x in line.split()[1:4]] for line in obj if line.startswith("v ")])
    np.testing.assert_allclose(vertices, face.vertices, atol=1e-5)
    # The exact surface reads back into the kernel.
    surface = splineface.BSplineSurface.from_json((tmp_path / "out" / "surface.json").read_text())
    assert surface.control_points.shape[2] == 3
    # The structure's eye centres lie the chosen eye distance apart.
    structure = json.loads((tmp_path / "out" / "structure.json").read_text())
    right, left = (np.array(structure["eye_centres"][k]) for k in ("right", "left"))
    assert abs(np.linalg.norm(right - left) - 63.0) < 1e-6
    # Saving over a file is refused.
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(splineface.SplinefaceError, match="exists and is not a directory"):
        face.save(blocker)


def test_points_only_and_settings(demo_photos):
    points_only = splineface.reconstruct(landmarks=demo_photos, units="canonical")
    assert points_only.texture is None
    assert points_only.units == "canonical"
    assert len(points_only.photos_used) == 6


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({}, splineface.SplinefaceError, "nothing to reconstruct"),
        ({"units": "inches"}, ValueError, "units=`inches`: expected mm or canonical"),
        ({"eye_distance": -1.0}, ValueError, "eye_distance=-1: must be positive"),
        ({"texture_size": 8}, ValueError, "texture_size=8: must be between 16 and 8192"),
        ({"shape": "blob"}, ValueError, "shape=`blob`"),
        ({"min_photos": 0}, ValueError, "min_photos=0: must be at least 1"),
    ],
)
def test_bad_settings_are_refused(kwargs, error, message):
    with pytest.raises(error, match=message):
        splineface.reconstruct(**kwargs)


def test_bad_inputs_are_refused(demo_photos, tmp_path):
    with pytest.raises(splineface.SplinefaceError, match="no such file"):
        splineface.reconstruct(photos=[tmp_path / "missing.png"], landmarks=demo_photos)
    with pytest.raises(splineface.SplinefaceError, match="the photos need landmarks"):
        splineface.reconstruct(photos=demo_photos)
    with pytest.raises(splineface.SplinefaceError, match="6 usable photos, at least 7 needed"):
        splineface.reconstruct(photos=demo_photos, landmarks=demo_photos, min_photos=7)
    with pytest.raises(ValueError, match="expression_of=nobody: no usable photo has that name"):
        splineface.reconstruct(photos=demo_photos, landmarks=demo_photos, expression_of="nobody")
    with pytest.raises(splineface.SplinefaceError, match="is not a folder"):
        splineface.reconstruct(photos=demo_photos, landmarks=tmp_path / "nowhere")
    with pytest.raises(TypeError, match="landmark_model: a path or a splineface.Landmarker"):
        splineface.reconstruct(photos=demo_photos, landmark_model=3.5)
    with pytest.raises(splineface.SplinefaceError, match="missing.dat"):
        splineface.Landmarker(tmp_path / "missing.dat")
    # The demo's settings are checked by the library and named as keywords; nothing is written.
    with pytest.raises(ValueError, match="noise=-1: must be a finite percentage"):
        splineface.write_demo_photos(tmp_path / "demo", photos=3, noise=-1.0)
    with pytest.raises(ValueError, match="photos=0: between 1 and 200"):
        splineface.write_demo_photos(tmp_path / "demo", photos=0)
    assert not (tmp_path / "demo").exists()
    # A damaged photo is skipped with its reason, not fatal.
    broken = tmp_path / "broken"
    broken.mkdir()
    for p in pathlib.Path(demo_photos).iterdir():
        (broken / p.name).write_bytes(p.read_bytes())
    first = sorted(broken.glob("*.png"))[0]
    first.write_bytes(first.read_bytes()[:100])
    face = splineface.reconstruct(photos=broken, landmarks=broken, refine=False, texture_size=64)
    assert len(face.photos_used) == 5
    assert len(face.photos_skipped) == 1 and first.name in face.photos_skipped[0]


@pytest.fixture(scope="module")
def landmarker(landmark_model):
    return splineface.Landmarker(landmark_model)


def read_photo(path):
    image = pytest.importorskip("PIL.Image")
    return np.ascontiguousarray(np.asarray(image.open(path).convert("RGB")))


def test_the_landmarker_finds_the_subject(landmarker, lps_photos):
    photo = read_photo(sorted(lps_photos.glob("*.png"))[0])
    faces = landmarker.detect(photo)
    assert len(faces) >= 1
    subject = landmarker.subject(photo)
    x, y, w, h = subject.box
    assert subject.points.shape == (68, 2)
    inside = (subject.points[:, 0] > x - 0.2 * w) & (subject.points[:, 0] < x + 1.2 * w)
    assert inside.all()
    assert subject.disagreement < 0.2
    # A grey image is taken as well (its three channels equal).
    grey = np.ascontiguousarray(photo.mean(axis=2).astype(np.uint8))
    assert landmarker.subject(grey).points.shape == (68, 2)
    # No face in a flat image.
    assert landmarker.detect(np.full((200, 200, 3), 128, dtype=np.uint8)) == []
    with pytest.raises(splineface.SplinefaceError, match="no face"):
        landmarker.subject(np.full((200, 200, 3), 128, dtype=np.uint8))
    with pytest.raises(TypeError, match="image: expected uint8 values, got dtype float64"):
        landmarker.detect(photo.astype(np.float64))
    with pytest.raises(ValueError, match=r"image: expected shape \(h, w\) or \(h, w, 3\)"):
        landmarker.detect(np.zeros((10, 10, 4), dtype=np.uint8))


def test_reconstruct_takes_a_loaded_landmarker(landmarker, lps_photos):
    face = splineface.reconstruct(photos=lps_photos, landmark_model=landmarker, texture_size=128)
    assert len(face.photos_used) >= 2
    assert [p["name"] for p in face.poses] == face.photos_used
    assert any(t["stage"] == "photos: decoding, detection, landmarks (in parallel)" for t in face.report["timings"])


def test_unknown_and_mistyped_settings_are_refused(demo_photos):
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'") as refused:
        splineface.reconstruct(landmarks=demo_photos, colour=True)
    # The refusal lists the settings the binding reads, which are those the stub declares.
    listed = str(refused.value).split("(the settings are ", 1)[1].rstrip(")").split(", ")
    stub = ast.parse((pathlib.Path(splineface.__file__).parent / "__init__.pyi").read_text())
    settings = next(c for c in stub.body if isinstance(c, ast.ClassDef) and c.name == "_Settings")
    declared = [a.target.id for a in settings.body if isinstance(a, ast.AnnAssign)]
    assert listed == declared
    with pytest.raises(TypeError, match="refine: expected True or False"):
        splineface.reconstruct(landmarks=demo_photos, refine="yes")
    with pytest.raises(TypeError, match="outline: expected True or False"):
        splineface.reconstruct(landmarks=demo_photos, outline=1)
    with pytest.raises(TypeError, match="lips: expected True or False"):
        splineface.reconstruct(landmarks=demo_photos, lips="off")
    with pytest.raises(TypeError, match="displacement: expected True or False"):
        splineface.reconstruct(landmarks=demo_photos, displacement="no")
    with pytest.raises(TypeError, match="min_photos: expected a whole number"):
        splineface.reconstruct(landmarks=demo_photos, min_photos=-2)
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
        splineface.reconstruct_subject(demo_photos, demo_photos.parent / "out", colour=True)
