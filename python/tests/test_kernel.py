"""The B-spline kernel from Python: closed-form oracles, scipy as an independent evaluator, and
bad arrays refused with the argument named."""

import json

import numpy as np
import pytest

import splineface


def grid_params(n=30):
    u, v = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    return np.column_stack([u.ravel(), v.ravel()])


def cubic_samples(params):
    """x = u, y = v, z = u² v + v³/2: inside the bicubic space, so a fit reproduces it exactly."""
    u, v = params[:, 0], params[:, 1]
    return np.column_stack([u, v, u * u * v + 0.5 * v**3])


def test_a_fit_reproduces_a_bicubic_polynomial_and_its_derivatives():
    params = grid_params()
    surface = splineface.BSplineSurface.fit(cubic_samples(params), params, shape=(8, 9))
    assert surface.fit_report["max"] < 1e-10
    assert surface.fit_report["samples"] == len(params)
    rng = np.random.default_rng(1)
    at = rng.uniform(0.0, 1.0, size=(200, 2))
    np.testing.assert_allclose(surface.eval(at), cubic_samples(at), atol=1e-10)
    d = surface.derivatives(at, 2)
    assert d.shape == (200, 3, 3, 3)
    u, v = at[:, 0], at[:, 1]
    np.testing.assert_allclose(d[:, 0, 0], cubic_samples(at), atol=1e-10)
    np.testing.assert_allclose(d[:, 1, 0, 2], 2 * u * v, atol=1e-9)  # ∂z/∂u
    np.testing.assert_allclose(d[:, 0, 1, 2], u * u + 1.5 * v * v, atol=1e-9)  # ∂z/∂v
    np.testing.assert_allclose(d[:, 1, 1, 2], 2 * u, atol=1e-8)  # ∂²z/∂u∂v
    np.testing.assert_allclose(d[:, 2, 0, 2], 2 * v, atol=1e-8)  # ∂²z/∂u²
    assert np.all(d[:, 2, 1] == 0) and np.all(d[:, 2, 2] == 0)  # beyond the order


def test_eval_grid_is_eval_on_the_grid():
    rng = np.random.default_rng(2)
    surface = splineface.BSplineSurface(rng.normal(size=(7, 5, 3)), degree_u=3, degree_v=2)
    us, vs = np.linspace(0, 1, 11), np.sort(rng.uniform(0, 1, 13))
    grid = surface.eval_grid(us, vs)
    assert grid.shape == (11, 13, 3)
    params = np.array([[u, v] for u in us for v in vs])
    # The grid is evaluated separably (rows first): the same to rounding.
    np.testing.assert_allclose(grid.reshape(-1, 3), surface.eval(params), rtol=0, atol=1e-13)


def test_a_plane_has_a_constant_normal():
    u, v = np.meshgrid(np.linspace(-1, 1, 4), np.linspace(-2, 2, 4), indexing="ij")
    control = np.stack([u, v, 0.3 * u + 0.1 * v + 2.0], axis=-1)
    surface = splineface.BSplineSurface(control)
    normals = surface.normal(grid_params(7))
    expected = np.array([-0.3, -0.1, 1.0]) / np.linalg.norm([-0.3, -0.1, 1.0])
    np.testing.assert_allclose(normals, np.tile(expected, (49, 1)), atol=1e-12)


def test_scipy_evaluates_the_same_surface():
    """scipy's FITPACK (bisplev) on the same knots and coefficients gives the same heights."""
    interpolate = pytest.importorskip("scipy.interpolate")
    rng = np.random.default_rng(3)
    rows, cols, p, q = 9, 7, 3, 3
    inner_u = np.sort(rng.uniform(0.1, 0.9, rows - p - 1))
    inner_v = np.sort(rng.uniform(0.1, 0.9, cols - q - 1))
    knots_u = np.concatenate([np.zeros(p + 1), inner_u, np.ones(p + 1)])
    knots_v = np.concatenate([np.zeros(q + 1), inner_v, np.ones(q + 1)])
    control = rng.normal(size=(rows, cols, 3))
    surface = splineface.BSplineSurface(control, p, q, knots_u, knots_v)
    np.testing.assert_array_equal(surface.knots_u, knots_u)
    us, vs = np.linspace(0, 1, 17), np.linspace(0, 1, 19)
    ours = surface.eval_grid(us, vs)
    for axis in range(3):
        tck = (knots_u, knots_v, control[:, :, axis].ravel(), p, q)
        theirs = interpolate.bisplev(us, vs, tck)
        np.testing.assert_allclose(ours[:, :, axis], theirs, atol=1e-12)


def test_weights_and_smoothness_change_the_fit_as_they_should():
    rng = np.random.default_rng(4)
    params = rng.uniform(0, 1, size=(2000, 2))
    points = cubic_samples(params)
    points[:, 2] += rng.normal(scale=0.05, size=len(params))
    plain = splineface.BSplineSurface.fit(points, params, shape=(10, 10))
    smooth = splineface.BSplineSurface.fit(points, params, shape=(10, 10), smoothness=1.0)
    assert smooth.fit_report["smoothness"] == 1.0
    assert smooth.fit_report["rms"] > plain.fit_report["rms"]
    # A sample with zero weight does not pull the surface.
    weights = np.ones(len(params))
    moved = points.copy()
    moved[0, 2] += 100.0
    weights[0] = 0.0
    ignored = splineface.BSplineSurface.fit(moved, params, shape=(10, 10), weights=weights)
    clean = splineface.BSplineSurface.fit(points, params, shape=(10, 10), weights=weights)
    np.testing.assert_allclose(ignored.control_points, clean.control_points, atol=1e-9)


def test_json_round_trips_exactly():
    rng = np.random.default_rng(5)
    surface = splineface.BSplineSurface(rng.normal(size=(6, 6, 3)))
    again = splineface.BSplineSurface.from_json(surface.to_json())
    np.testing.assert_array_equal(again.control_points, surface.control_points)
    assert json.loads(surface.to_json())["format"].startswith("splineface")
    with pytest.raises(ValueError, match="not a splineface surface"):
        splineface.BSplineSurface.from_json("{}")


def test_lists_are_taken_as_arrays():
    surface = splineface.BSplineSurface(np.zeros((4, 4, 3)))
    assert surface.eval([[0.5, 0.5]]).shape == (1, 3)


@pytest.mark.parametrize(
    "call, error, message",
    [
        (lambda s: s.eval(np.zeros((3, 2), dtype=np.int64)), TypeError, "params: expected float64 values, got dtype int64"),
        (lambda s: s.eval(np.zeros((3, 3))), ValueError, r"params: expected shape \(n, 2\), got \[3, 3\]"),
        (lambda s: s.eval(np.array([[0.5, np.nan]])), ValueError, "params: entry 0 is not finite"),
        (lambda s: s.eval(np.zeros((4, 4))[:, :2]), ValueError, "params: the array is not C-contiguous"),
        (lambda s: s.eval(np.array([[1.5, 0.5]])), ValueError, "1.5"),
        (lambda s: s.eval(["a", "b"]), TypeError, "params: not an array of float64 values"),
        (lambda s: s.eval_grid(np.zeros((2, 2)), np.zeros(2)), ValueError, "us: expected shape"),
        (lambda s: s.derivatives(np.zeros((1, 2)), 17), ValueError, "order: 17"),
    ],
)
def test_bad_arrays_are_refused_naming_the_argument(call, error, message):
    surface = splineface.BSplineSurface(np.zeros((4, 4, 3)))
    with pytest.raises(error, match=message):
        call(surface)


def test_bad_grids_and_fits_are_refused():
    with pytest.raises(ValueError, match=r"control_points: expected shape \(n, n, 3\)"):
        splineface.BSplineSurface(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="control_points: entry 1 is not finite"):
        control = np.zeros((4, 4, 3))
        control[1, 2, 0] = np.inf
        splineface.BSplineSurface(control)
    with pytest.raises(ValueError, match="knots_u: 8 knots of degree 3 carry 4 control points, the grid has 5"):
        splineface.BSplineSurface(np.zeros((5, 4, 3)), knots_u=np.array([0, 0, 0, 0, 1, 1, 1, 1.0]))
    params = grid_params(5)
    with pytest.raises(ValueError, match="params: 25 rows for 24 points"):
        splineface.BSplineSurface.fit(cubic_samples(params)[:24], params, shape=(4, 4))
    with pytest.raises(ValueError, match="weights: expected shape"):
        splineface.BSplineSurface.fit(cubic_samples(params), params, shape=(4, 4), weights=np.ones(3))
    with pytest.raises(TypeError, match="degree: an int or a"):
        splineface.BSplineSurface.fit(cubic_samples(params), params, shape=(4, 4), degree="cubic")
    # Too few samples for the grid: the kernel names the free control point.
    with pytest.raises(ValueError, match="control point"):
        splineface.BSplineSurface.fit(cubic_samples(params), params, shape=(12, 12))


def test_closest_points_on_a_plane_are_the_feet_of_the_perpendiculars():
    # z = 0 over [0, 3]²: the closest point to (x, y, h) is (x, y, 0), at (u, v) = (x, y) / 3.
    i, j = np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij")
    grid = np.stack([i, j, np.zeros_like(i)], axis=-1)
    plane = splineface.BSplineSurface(grid, degree_u=3, degree_v=3)
    rng = np.random.default_rng(3)
    queries = np.column_stack([rng.uniform(0, 3, 50), rng.uniform(0, 3, 50), rng.uniform(-2, 2, 50)])
    found = plane.closest(queries)
    np.testing.assert_allclose(found["params"], queries[:, :2] / 3.0, atol=1e-12)
    np.testing.assert_allclose(found["points"][:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(found["distances"], np.abs(queries[:, 2]), atol=1e-12)


def test_closest_points_on_a_curved_surface_beat_a_dense_search_and_are_stationary():
    rng = np.random.default_rng(4)
    i, j = np.meshgrid(np.arange(6.0), np.arange(6.0), indexing="ij")
    grid = np.stack([i, j, 0.4 * rng.standard_normal(i.shape)], axis=-1)
    surface = splineface.BSplineSurface(grid)
    dense = surface.eval(grid_params(201))
    queries = surface.eval(rng.uniform(0, 1, (40, 2))) + 0.3 * rng.standard_normal((40, 3))
    found = surface.closest(queries)
    for q, d in zip(queries, found["distances"]):
        assert d <= np.min(np.linalg.norm(dense - q, axis=1)) + 1e-9
    # Inside the domain the residual is normal to the surface.
    inside = np.all((found["params"] > 1e-6) & (found["params"] < 1 - 1e-6), axis=1)
    d = surface.derivatives(found["params"][inside], order=1)
    r = queries[inside] - found["points"][inside]
    for du, dv, residual in zip(d[:, 1, 0], d[:, 0, 1], r):
        scale = np.linalg.norm(residual) + 1e-300
        assert abs(du @ residual) <= 1e-8 * scale * np.linalg.norm(du)
        assert abs(dv @ residual) <= 1e-8 * scale * np.linalg.norm(dv)
    # The index the first call built answers the next calls, one point at a time too.
    again = surface.closest(queries)
    for key in ("params", "points", "distances"):
        np.testing.assert_array_equal(again[key], found[key])
    one = surface.closest(queries[7:8])
    np.testing.assert_array_equal(one["params"], found["params"][7:8])


def test_step_text_is_the_whole_surface_or_a_trimmed_face():
    i, j = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    surface = splineface.BSplineSurface(np.stack([i, j, (i - 2) * (j - 2) / 4], axis=-1))
    whole = surface.to_step(name="patch")
    assert whole.startswith("ISO-10303-21;") and "B_SPLINE_SURFACE_WITH_KNOTS('patch'" in whole
    assert "ADVANCED_FACE" not in whole
    triangle = np.array([[0.1, 0.1], [0.9, 0.2], [0.5, 0.9]])
    trimmed = surface.to_step(trim=triangle)
    assert trimmed.count("ADVANCED_FACE(") == 1
    assert trimmed.count("B_SPLINE_CURVE_WITH_KNOTS(") == 2  # in space and in (u, v)
    with pytest.raises(ValueError, match="trim"):
        surface.to_step(trim=triangle[:2])
    with pytest.raises(ValueError, match="trim"):
        surface.to_step(trim=triangle + 1.0)
    assert "SI_UNIT(.MILLI.,.METRE.)" in whole
    metres = surface.to_step(name="patch", units="m")
    assert "SI_UNIT($,.METRE.)" in metres
    assert metres.replace("SI_UNIT($,.METRE.)", "") == whole.replace("SI_UNIT(.MILLI.,.METRE.)", "")
    with pytest.raises(ValueError, match="units"):
        surface.to_step(units="furlong")
