"""A batch of subjects on a Dask cluster, through the splineface package.

    python dask_batch.py SUBJECTS OUT [--scheduler tcp://HOST:8786] [--landmark-model PATH] [--workers N]

SUBJECTS holds one folder per subject (its photos and/or landmark files), as for
``splineface batch``. Without ``--scheduler`` a LocalCluster of ``--workers`` processes runs
here; with it, the same code runs on that scheduler's workers, which need the splineface
wheel installed and SUBJECTS, OUT and the model at the same paths (a shared file system).
Each worker loads the landmark model once. The results are gathered into OUT/summary.csv and
OUT/summary.jsonl, the same files ``splineface batch`` writes; a subject whose outputs are up
to date is skipped, so a batch resumes where it stopped.
"""

import argparse
import sys

import splineface

# One Landmarker per worker process, loaded on the worker's first subject.
_landmarkers = {}


def reconstruct_on_worker(folder, out, landmark_model=None, settings=None):
    """splineface.reconstruct_subject, with the worker's cached landmark model."""
    model = None
    if landmark_model is not None:
        model = _landmarkers.get(landmark_model)
        if model is None:
            model = _landmarkers[landmark_model] = splineface.Landmarker(landmark_model)
    return splineface.reconstruct_subject(folder, out, landmark_model=model, **(settings or {}))


def run(client, root, out, landmark_model=None, **settings):
    """Maps the subjects of root over client's workers; writes and returns the summary rows."""
    subjects = [str(s) for s in splineface.batch_subjects(root, out)]
    futures = client.map(
        reconstruct_on_worker,
        subjects,
        out=str(out),
        landmark_model=None if landmark_model is None else str(landmark_model),
        settings=settings,
        pure=False,
    )
    rows = client.gather(futures)
    splineface.write_summary(out, rows)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root")
    parser.add_argument("out")
    parser.add_argument("--scheduler", help="a Dask scheduler's address (default: a LocalCluster here)")
    parser.add_argument("--landmark-model")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    from dask.distributed import Client, LocalCluster

    if args.scheduler:
        client = Client(args.scheduler)
    else:
        client = Client(LocalCluster(n_workers=args.workers, threads_per_worker=1))
    with client:
        rows = run(client, args.root, args.out, args.landmark_model)
    failed = [r for r in rows if r["status"] == "failed"]
    print(f"{args.out}: {len(rows)} subjects, {len(failed)} failed")
    for r in failed:
        print(f"  {r['subject']}: {r['message']}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
