"""splineface's kernel against scipy's FITPACK, side by side in one process, from Python.

    python python/bench/bench_scipy.py [--repeat 5]

The same cubic surface (32 × 32 control points, clamped uniform knots on [0, 1]) is evaluated
on a dense grid (splineface eval_grid against scipy.interpolate.bisplev) and at scattered points
(eval against LSQBivariateSpline.ev); and fitted by least squares to scattered samples on the
same knots (BSplineSurface.fit against LSQBivariateSpline). scipy's splines are scalar: it
evaluates and fits z alone, splineface all three coordinates, so the per-coordinate ratio is
printed too. Each figure is the best of --repeat runs; the interpreter is released during
splineface's calls, but every call here runs on the calling thread's rayon pool (both cores).
"""

import argparse
import time

import numpy as np
import scipy
from scipy import interpolate

import splineface


def best(repeat, call):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = call()
        times.append(time.perf_counter() - start)
    return min(times), result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    n, p = 32, 3
    inner = np.linspace(0, 1, n - p + 1)[1:-1]
    knots = np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])
    control = rng.normal(size=(n, n, 3))
    ours = splineface.BSplineSurface(control, p, p, knots, knots)
    tck = (knots, knots, control[:, :, 2].ravel(), p, p)
    print(f"splineface {splineface.__version__}, scipy {scipy.__version__}, numpy {np.__version__}")
    print(f"{'operation':44} {'splineface':>12} {'scipy':>12} {'ratio':>7} {'per coord':>9}")

    def row(name, ours_s, theirs_s, count, unit):
        ratio = theirs_s / ours_s
        print(f"{name:44} {count / ours_s / 1e6:9.2f} M{unit} {count / theirs_s / 1e6:9.2f} M{unit} "
              f"{ratio:6.1f}× {3 * ratio:8.1f}×")

    # Dense grid.
    side = 1000
    us = np.linspace(0, 1, side)
    ours_s, grid = best(args.repeat, lambda: ours.eval_grid(us, us))
    theirs_s, z = best(args.repeat, lambda: interpolate.bisplev(us, us, tck))
    assert np.allclose(grid[:, :, 2], z, atol=1e-10)
    row(f"grid {side} × {side} (points/s)", ours_s, theirs_s, side * side, "/s")

    # Scattered points.
    m = 1_000_000
    params = np.ascontiguousarray(rng.uniform(0, 1, size=(m, 2)))
    spline = interpolate.LSQBivariateSpline(
        rng.uniform(0, 1, 5000), rng.uniform(0, 1, 5000), rng.normal(size=5000), inner, inner, kx=p, ky=p)
    spline.tck = tck[:3]  # evaluate the same surface (the degrees are already 3, 3)
    spline.fp = 0.0
    ours_s, points = best(args.repeat, lambda: ours.eval(params))
    theirs_s, z = best(args.repeat, lambda: spline.ev(params[:, 0], params[:, 1]))
    assert np.allclose(points[:, 2], z, atol=1e-10)
    row(f"scattered, {m:,} points (points/s)", ours_s, theirs_s, m, "/s")

    # Least-squares fit to scattered samples on the same knots.
    for samples in (20_000, 200_000):
        fit_params = np.ascontiguousarray(rng.uniform(0, 1, size=(samples, 2)))
        truth = ours.eval(fit_params)
        noisy = truth + rng.normal(scale=0.01, size=truth.shape)
        x, y, zz = fit_params[:, 0].copy(), fit_params[:, 1].copy(), noisy[:, 2].copy()
        ours_s, fitted = best(args.repeat, lambda: splineface.BSplineSurface.fit(
            noisy, fit_params, shape=(n, n), knots_u=knots, knots_v=knots))
        theirs_s, lsq = best(args.repeat, lambda: interpolate.LSQBivariateSpline(
            x, y, zz, inner, inner, bbox=[0, 1, 0, 1], kx=p, ky=p))
        # The same least-squares problem: the same z coefficients.
        assert np.allclose(fitted.control_points[:, :, 2].ravel(), lsq.get_coeffs(), atol=1e-6)
        row(f"fit 32 × 32 to {samples:,} samples (samples/s)", ours_s, theirs_s, samples, "/s")
        print(f"{'':44} {1e3 * ours_s:10.1f} ms {1e3 * theirs_s:10.1f} ms")


if __name__ == "__main__":
    main()
