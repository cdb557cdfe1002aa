"""Shared fixtures: the demo subject's photos (rendered once per session) and, when present,
dlib's landmark model and the real scan's photos from ../shared."""

import os
import pathlib

import pytest

import splineface

REPOSITORY = pathlib.Path(__file__).resolve().parents[2]
SHARED = REPOSITORY.parent / "shared"


@pytest.fixture(scope="session")
def demo_photos(tmp_path_factory):
    """Six rendered photos of the demo subject with their landmark files."""
    folder = tmp_path_factory.mktemp("demo")
    splineface.write_demo_photos(folder, photos=6, noise=1.0, seed=7)
    return folder


@pytest.fixture(scope="session")
def landmark_model():
    """dlib's model: $SPLINEFACE_LANDMARK_MODEL or ../shared/models; the test is skipped without."""
    candidates = [os.environ.get("SPLINEFACE_LANDMARK_MODEL"),
                  SHARED / "models" / "shape_predictor_68_face_landmarks.dat"]
    for candidate in candidates:
        if candidate and pathlib.Path(candidate).is_file():
            return pathlib.Path(candidate)
    pytest.skip("needs dlib's landmark model (SPLINEFACE_LANDMARK_MODEL or ../shared/models)")


@pytest.fixture(scope="session")
def lps_photos():
    folder = SHARED / "data" / "lps-head" / "photos-3"
    if not folder.is_dir():
        pytest.skip("needs ../shared/data/lps-head")
    return folder
