"""The cluster path: reconstruct_subject mapped over a Dask LocalCluster's worker processes
(python/examples/dask_batch.py), gathered into the summary splineface batch writes."""

import csv
import importlib.util
import json
import pathlib

import pytest

import splineface

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "dask_batch.py"


def load_example():
    spec = importlib.util.spec_from_file_location("dask_batch", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def subjects(tmp_path_factory):
    root = tmp_path_factory.mktemp("subjects")
    for name, seed in [("alice", 1), ("bob", 2), ("carol", 3)]:
        splineface.write_demo_photos(root / name, photos=3, seed=seed)
    (root / "empty").mkdir()
    return root


def test_reconstruct_subject_is_one_row_of_a_batch(subjects, tmp_path):
    out = tmp_path / "out"
    row = splineface.reconstruct_subject(subjects / "alice", out, refine=False, texture_size=64)
    assert row["status"] == "done" and row["photos_used"] == 3
    assert (out / "alice" / "face.obj").is_file()
    again = splineface.reconstruct_subject(subjects / "alice", out, refine=False, texture_size=64)
    assert again["status"] == "unchanged"
    failed = splineface.reconstruct_subject(subjects / "empty", out)
    assert failed["status"] == "failed" and "no photos or landmark files" in failed["message"]
    with pytest.raises(splineface.SplinefaceError, match="the output lies inside the input folder"):
        splineface.batch_subjects(subjects, subjects / "results")
    with pytest.raises(ValueError, match="rows\\[0\\]: not a subject row"):
        splineface.write_summary(out, [{"subject": "x"}])


def test_a_local_dask_cluster_runs_the_batch(subjects, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    example = load_example()
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        with distributed.Client(cluster) as client:
            rows = example.run(client, subjects, out, refine=False, texture_size=64)
            assert len(set(client.run(lambda: __import__("os").getpid()).values())) == 2
    assert sorted((r["subject"], r["status"]) for r in rows) == [
        ("alice", "done"), ("bob", "done"), ("carol", "done"), ("empty", "failed")]
    with open(out / "summary.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [r["subject"] for r in table] == ["alice", "bob", "carol", "empty"]
    assert [r["status"] for r in table] == ["done", "done", "done", "failed"]
    lines = (out / "summary.jsonl").read_text().splitlines()
    assert json.loads(lines[0])["photos_used"] == 3
    # The same subjects through the command line's batch give the same summary columns.
    assert list(table[0]) == ["subject", "status", "photos_given", "photos_used", "photos_dropped",
                              "photos_skipped", "seconds", "similarity", "fit_rms_pixels", "refined",
                              "vertices", "message"]
