//! The Python module `splineface._native`, re-exported by the `splineface` package
//! (`python/pysrc/splineface/__init__.py`, typed by `__init__.pyi`).
//!
//! Arrays cross as numpy arrays: float64 (and uint8 images), C-contiguous, of the stated shapes;
//! anything else is refused with an exception naming the argument (a Python list is converted
//! first). Work on the arrays runs with the interpreter released, so Python threads (and Dask
//! workers) run beside it.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Point3;
use numpy::ndarray::{Array, IxDyn};
use numpy::{
    Element, IntoPyArray, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyException, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use splineface::bspline::{BSplineError, BSplineSurface, KnotVector, SurfaceFit};
use splineface::landmarker::ShapePredictor;
use splineface::pipeline::{PhotoSet, Settings};
use splineface::reference::ReferenceFace;

pyo3::create_exception!(
    splineface,
    SplinefaceError,
    PyException,
    "A reconstruction, a model or a file that could not be used; the message names the file or \
     stage and the problem."
);

// --- arrays in and out -------------------------------------------------------------------------

/// `value` as a numpy array (a list or tuple is converted with `numpy.asarray`), refused unless
/// its values are `T` and it is C-contiguous, with an exception naming `name`.
fn array_of<'py, T: Element>(
    value: &Bound<'py, PyAny>,
    name: &str,
    kind: &str,
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let py = value.py();
    let value = if value.cast::<PyUntypedArray>().is_ok() {
        value.clone()
    } else {
        let numpy = py.import("numpy")?;
        let dtype = numpy::dtype::<T>(py);
        numpy
            .call_method1("asarray", (value, dtype))
            .map_err(|e| PyTypeError::new_err(format!("{name}: not an array of {kind} values ({e})")))?
    };
    let untyped = value.cast::<PyUntypedArray>()?;
    if !untyped.dtype().is_equiv_to(&numpy::dtype::<T>(py)) {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected {kind} values, got dtype {} (convert with .astype(numpy.{kind}))",
            untyped.dtype()
        )));
    }
    if !untyped.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "{name}: the array is not C-contiguous (pass numpy.ascontiguousarray({name}))"
        )));
    }
    Ok(value.cast_into::<PyArrayDyn<T>>()?)
}

/// The values and shape of a float64 array whose shape matches `shape` (`None` for any
/// length), every value finite.
fn floats(value: &Bound<'_, PyAny>, name: &str, shape: &[Option<usize>]) -> PyResult<(Vec<f64>, Vec<usize>)> {
    let array = array_of::<f64>(value, name, "float64")?;
    let dims = array.shape().to_vec();
    let wanted = || {
        let parts: Vec<String> = shape
            .iter()
            .map(|d| d.map_or_else(|| "n".to_owned(), |d| d.to_string()))
            .collect();
        format!("({})", parts.join(", "))
    };
    if dims.len() != shape.len() || dims.iter().zip(shape).any(|(d, s)| s.is_some_and(|s| s != *d)) {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape {}, got {dims:?}",
            wanted()
        )));
    }
    let values = array.readonly().as_slice()?.to_vec();
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        let row = if dims.len() > 1 {
            k / dims[1..].iter().product::<usize>()
        } else {
            k
        };
        return Err(PyValueError::new_err(format!(
            "{name}: entry {row} is not finite (NaN or infinity)"
        )));
    }
    Ok((values, dims))
}

/// `n × 2` parameters as `[u, v]` pairs.
fn params_of(value: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f64; 2]>> {
    let (values, _) = floats(value, name, &[None, Some(2)])?;
    Ok(values.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
}

/// A numpy array of `shape` from `values`.
fn to_numpy<'py, T: Element>(
    py: Python<'py>,
    values: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let array = Array::from_shape_vec(IxDyn(shape), values)
        .map_err(|e| PyValueError::new_err(format!("internal shape error: {e}")))?;
    Ok(array.into_pyarray(py))
}

/// A copy of `values` as a numpy array of `shape`, as a Python object.
fn copied<T: Element + Clone>(py: Python<'_>, values: &[T], shape: &[usize]) -> PyResult<Py<PyAny>> {
    Ok(to_numpy(py, values.to_vec(), shape)?.into_any().unbind())
}

/// Points as a numpy array of `shape` (`…, 3`), their buffer handed over without a copy.
fn points_to_numpy(py: Python<'_>, points: Vec<Point3<f64>>, shape: &[usize]) -> PyResult<Py<PyAny>> {
    Ok(to_numpy(py, coordinates(points), shape)?.into_any().unbind())
}

/// The coordinates of `points`, `x, y, z` after each other, in the same allocation.
fn coordinates(points: Vec<Point3<f64>>) -> Vec<f64> {
    const {
        assert!(std::mem::size_of::<Point3<f64>>() == 3 * std::mem::size_of::<f64>());
        assert!(std::mem::align_of::<Point3<f64>>() == std::mem::align_of::<f64>());
    }
    let mut points = std::mem::ManuallyDrop::new(points);
    let (pointer, length, capacity) = (points.as_mut_ptr(), points.len(), points.capacity());
    // SAFETY: `Point3<f64>` is `#[repr(C)]` around nalgebra's `#[repr(C)]` array storage
    // `[[f64; 3]; 1]`: three `f64`s with `f64`'s alignment and no padding (checked above), so
    // an allocation of `capacity` points is one of `3 · capacity` floats, allocated with the
    // same alignment, and its first `3 · length` floats are initialised.
    unsafe { Vec::from_raw_parts(pointer.cast::<f64>(), 3 * length, 3 * capacity) }
}

fn kernel_error(error: BSplineError) -> PyErr {
    PyValueError::new_err(error.to_string())
}

/// A setting out of range as a `ValueError` naming the keyword: `keyword=value: expected`.
fn setting_error(error: &splineface::error::SettingError) -> PyErr {
    PyValueError::new_err(format!("{}={}: {}", error.setting, error.value, error.expected))
}

/// The library's error: a setting as [`setting_error`], anything else a `SplinefaceError`
/// with the library's message.
fn library_error(error: splineface::Error) -> PyErr {
    match &error {
        splineface::Error::Setting(setting) => setting_error(setting),
        splineface::Error::Demo(splineface::demo::DemoError::Setting(setting)) => setting_error(setting),
        _ => SplinefaceError::new_err(error.to_string()),
    }
}

// --- the kernel ---------------------------------------------------------------------------------

/// A tensor-product B-spline surface `F(u, v) = Σᵢⱼ Nᵢ,ₚ(u) Nⱼ,q(v) Pᵢⱼ` with a
/// `rows × cols` grid of 3D control points (splineface's `bspline::BSplineSurface`).
#[pyclass(frozen, name = "BSplineSurface", module = "splineface")]
struct BSplineSurfaceHandle {
    surface: BSplineSurface,
    report: Option<splineface::bspline::FitReport>,
    /// The closest-point index, built by the first `closest` and kept (the surface never
    /// changes: the class is frozen).
    index: std::sync::OnceLock<splineface::bspline::ClosestPoints<'static>>,
}

impl BSplineSurfaceHandle {
    fn wrap(surface: BSplineSurface, report: Option<splineface::bspline::FitReport>) -> Self {
        BSplineSurfaceHandle {
            surface,
            report,
            index: std::sync::OnceLock::new(),
        }
    }
}

fn knots_or_uniform(
    knots: Option<&Bound<'_, PyAny>>,
    name: &str,
    degree: usize,
    count: usize,
) -> PyResult<KnotVector> {
    match knots {
        Some(k) => {
            let (values, _) = floats(k, name, &[None])?;
            let knots =
                KnotVector::new(degree, values).map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
            if knots.num_control_points() != count {
                return Err(PyValueError::new_err(format!(
                    "{name}: {} knots of degree {degree} carry {} control points, the grid has {count} (knots = control points + degree + 1)",
                    knots.knots().len(),
                    knots.num_control_points()
                )));
            }
            Ok(knots)
        }
        None => KnotVector::clamped_uniform(degree, count, 0.0, 1.0)
            .map_err(|e| PyValueError::new_err(format!("{name}: {e}"))),
    }
}

#[pymethods]
impl BSplineSurfaceHandle {
    /// `control_points`: float64 `(rows, cols, 3)`; `knots_u` (`rows + degree_u + 1` values)
    /// and `knots_v` default to clamped uniform knots over `[0, 1]`.
    #[new]
    #[pyo3(signature = (control_points, degree_u = 3, degree_v = 3, knots_u = None, knots_v = None))]
    fn new(
        control_points: &Bound<'_, PyAny>,
        degree_u: usize,
        degree_v: usize,
        knots_u: Option<&Bound<'_, PyAny>>,
        knots_v: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let (values, dims) = floats(control_points, "control_points", &[None, None, Some(3)])?;
        let (rows, cols) = (dims[0], dims[1]);
        let knots_u = knots_or_uniform(knots_u, "knots_u", degree_u, rows)?;
        let knots_v = knots_or_uniform(knots_v, "knots_v", degree_v, cols)?;
        let points = values
            .chunks_exact(3)
            .map(|c| Point3::new(c[0], c[1], c[2]))
            .collect();
        let surface = BSplineSurface::new(knots_u, knots_v, rows, cols, points).map_err(kernel_error)?;
        Ok(BSplineSurfaceHandle::wrap(surface, None))
    }

    /// Least-squares fit of a `shape = (rows, cols)` control grid to `points` (float64
    /// `(n, 3)`) at `params` (float64 `(n, 2)`, inside the knots' domain), with optional
    /// per-sample `weights` (`(n,)`, ≥ 0) and a thin-plate `smoothness` λ ≥ 0. Knots default
    /// to clamped uniform over `[0, 1]` of degree `degree` (an int or a `(p, q)` pair).
    #[staticmethod]
    #[pyo3(signature = (points, params, shape, degree = None, knots_u = None, knots_v = None, weights = None, smoothness = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn fit(
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        params: &Bound<'_, PyAny>,
        shape: (usize, usize),
        degree: Option<&Bound<'_, PyAny>>,
        knots_u: Option<&Bound<'_, PyAny>>,
        knots_v: Option<&Bound<'_, PyAny>>,
        weights: Option<&Bound<'_, PyAny>>,
        smoothness: f64,
    ) -> PyResult<Self> {
        let (p, q) = match degree {
            None => (3, 3),
            Some(d) => match d.extract::<usize>() {
                Ok(d) => (d, d),
                Err(_) => d
                    .extract::<(usize, usize)>()
                    .map_err(|_| PyTypeError::new_err("degree: an int or a (p, q) pair of ints"))?,
            },
        };
        let (values, dims) = floats(points, "points", &[None, Some(3)])?;
        let params = params_of(params, "params")?;
        if params.len() != dims[0] {
            return Err(PyValueError::new_err(format!(
                "params: {} rows for {} points",
                params.len(),
                dims[0]
            )));
        }
        let weights = match weights {
            Some(w) => {
                let (w, _) = floats(w, "weights", &[Some(dims[0])])?;
                Some(w)
            }
            None => None,
        };
        let knots_u = knots_or_uniform(knots_u, "knots_u", p, shape.0)?;
        let knots_v = knots_or_uniform(knots_v, "knots_v", q, shape.1)?;
        let points: Vec<Point3<f64>> = values
            .chunks_exact(3)
            .map(|c| Point3::new(c[0], c[1], c[2]))
            .collect();
        let fitted = py.detach(|| {
            let mut fit = SurfaceFit::new(knots_u, knots_v).smoothness(smoothness);
            if let Some(w) = &weights {
                fit = fit.weights(w);
            }
            fit.fit(&params, &points)
        });
        let fitted = fitted.map_err(kernel_error)?;
        Ok(BSplineSurfaceHandle::wrap(fitted.surface, Some(fitted.report)))
    }

    /// The surface at `params` (float64 `(n, 2)`): float64 `(n, 3)`.
    fn eval(&self, py: Python<'_>, params: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let params = params_of(params, "params")?;
        let points = py
            .detach(|| self.surface.eval_many(&params))
            .map_err(kernel_error)?;
        let n = points.len();
        points_to_numpy(py, points, &[n, 3])
    }

    /// The surface on the grid `us × vs` (float64 `(a,)` and `(b,)`): float64 `(a, b, 3)`,
    /// `[i, k] = F(us[i], vs[k])`.
    fn eval_grid(&self, py: Python<'_>, us: &Bound<'_, PyAny>, vs: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let (us, _) = floats(us, "us", &[None])?;
        let (vs, _) = floats(vs, "vs", &[None])?;
        let points = py
            .detach(|| self.surface.eval_grid(&us, &vs))
            .map_err(kernel_error)?;
        points_to_numpy(py, points, &[us.len(), vs.len(), 3])
    }

    /// Partial derivatives up to total order `order` at `params` (float64 `(n, 2)`): float64
    /// `(n, order + 1, order + 1, 3)`, `[s, k, l] = ∂ᵏ⁺ˡF/∂uᵏ∂vˡ` (zero where `k + l > order`).
    #[pyo3(signature = (params, order = 1))]
    fn derivatives(&self, py: Python<'_>, params: &Bound<'_, PyAny>, order: usize) -> PyResult<Py<PyAny>> {
        if order > 16 {
            return Err(PyValueError::new_err(format!("order: {order}; at most 16")));
        }
        let params = params_of(params, "params")?;
        let m = order + 1;
        let values = py.detach(|| -> Result<Vec<f64>, BSplineError> {
            let mut out = Vec::with_capacity(params.len() * m * m * 3);
            for &[u, v] in &params {
                let d = self.surface.derivatives(u, v, order)?;
                for k in 0..m {
                    for l in 0..m {
                        let x = if k + l <= order {
                            d.get(k, l)
                        } else {
                            nalgebra::Vector3::zeros()
                        };
                        out.extend([x.x, x.y, x.z]);
                    }
                }
            }
            Ok(out)
        });
        let values = values.map_err(kernel_error)?;
        Ok(to_numpy(py, values, &[params.len(), m, m, 3])?
            .into_any()
            .unbind())
    }

    /// Unit normals `F_u × F_v / |F_u × F_v|` at `params` (float64 `(n, 2)`): float64
    /// `(n, 3)`, NaN where the surface is degenerate.
    fn normal(&self, py: Python<'_>, params: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let params = params_of(params, "params")?;
        let values = py.detach(|| -> Result<Vec<f64>, BSplineError> {
            let mut out = Vec::with_capacity(params.len() * 3);
            for &[u, v] in &params {
                match self.surface.normal(u, v)? {
                    Some(n) => out.extend([n.x, n.y, n.z]),
                    None => out.extend([f64::NAN; 3]),
                }
            }
            Ok(out)
        });
        let values = values.map_err(kernel_error)?;
        Ok(to_numpy(py, values, &[params.len(), 3])?.into_any().unbind())
    }

    /// The closest points of the surface to `points` (float64 `(n, 3)`), in parallel: a dict
    /// of `params` float64 `(n, 2)`, `points` `(n, 3)` and `distances` `(n,)` (Newton from
    /// the nearest of a sampling, checked against every knot span that comes nearer). The
    /// index it searches is built by the first call (a few milliseconds) and kept.
    fn closest<'py>(&self, py: Python<'py>, points: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
        let (values, _) = floats(points, "points", &[None, Some(3)])?;
        let queries: Vec<Point3<f64>> = values
            .chunks_exact(3)
            .map(|c| Point3::new(c[0], c[1], c[2]))
            .collect();
        let found = py
            .detach(|| {
                self.index
                    .get_or_init(|| splineface::bspline::ClosestPoints::owning(self.surface.clone()))
                    .closest_many(&queries)
            })
            .map_err(kernel_error)?;
        let n = found.len();
        let out = PyDict::new(py);
        out.set_item(
            "params",
            to_numpy(py, found.iter().flat_map(|c| [c.u, c.v]).collect(), &[n, 2])?,
        )?;
        out.set_item(
            "points",
            points_to_numpy(py, found.iter().map(|c| c.point).collect(), &[n, 3])?,
        )?;
        out.set_item(
            "distances",
            to_numpy(py, found.iter().map(|c| c.distance).collect(), &[n])?,
        )?;
        Ok(out)
    }

    /// The surface as STEP AP214 text (`splineface::bspline::encode_step`): the exact spline,
    /// whole, or trimmed to `trim`, a closed polygon in `(u, v)` (float64 `(m, 2)`, `m ≥ 3`),
    /// as one face bounded by the polygon and its exact image on the surface. `units` (`"mm"`,
    /// `"cm"` or `"m"`) is the length unit the file declares for the coordinates as they are.
    #[pyo3(signature = (name = "surface", description = "", trim = None, units = "mm"))]
    fn to_step(
        &self,
        name: &str,
        description: &str,
        trim: Option<&Bound<'_, PyAny>>,
        units: &str,
    ) -> PyResult<String> {
        let unit = splineface::geometry::LengthUnit::parse(units).ok_or_else(|| {
            PyValueError::new_err(format!("units={units:?}: expected \"mm\", \"cm\" or \"m\""))
        })?;
        let trim: Vec<nalgebra::Point2<f64>> = match trim {
            Some(t) => params_of(t, "trim")?
                .into_iter()
                .map(|[u, v]| nalgebra::Point2::new(u, v))
                .collect(),
            None => Vec::new(),
        };
        splineface::bspline::encode_step(
            &self.surface,
            &splineface::bspline::StepOptions {
                name,
                description,
                unit,
                trim: &trim,
            },
        )
        .map_err(|e| PyValueError::new_err(format!("trim: {e}")))
    }

    /// The control grid: float64 `(rows, cols, 3)` (a copy).
    #[getter]
    fn control_points(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        points_to_numpy(
            py,
            self.surface.control_points().to_vec(),
            &[self.surface.rows(), self.surface.cols(), 3],
        )
    }

    /// The knots in `u`: float64 `(rows + degree_u + 1,)`.
    #[getter]
    fn knots_u(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let k = self.surface.knots_u().knots().to_vec();
        let n = k.len();
        Ok(to_numpy(py, k, &[n])?.into_any().unbind())
    }

    /// The knots in `v`: float64 `(cols + degree_v + 1,)`.
    #[getter]
    fn knots_v(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let k = self.surface.knots_v().knots().to_vec();
        let n = k.len();
        Ok(to_numpy(py, k, &[n])?.into_any().unbind())
    }

    #[getter]
    fn degree_u(&self) -> usize {
        self.surface.degree_u()
    }

    #[getter]
    fn degree_v(&self) -> usize {
        self.surface.degree_v()
    }

    /// `(u_min, u_max)`.
    #[getter]
    fn domain_u(&self) -> (f64, f64) {
        self.surface.domain_u()
    }

    /// `(v_min, v_max)`.
    #[getter]
    fn domain_v(&self) -> (f64, f64) {
        self.surface.domain_v()
    }

    /// How a fitted surface fits its samples (`samples`, `rms`, `max`, `max_index`,
    /// `smoothness`), else `None`.
    #[getter]
    fn fit_report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(r) = self.report else { return Ok(None) };
        let d = PyDict::new(py);
        d.set_item("samples", r.samples)?;
        d.set_item("rms", r.rms)?;
        d.set_item("max", r.max)?;
        d.set_item("max_index", r.max_index)?;
        d.set_item("smoothness", r.smoothness)?;
        Ok(Some(d))
    }

    /// The exact, versioned JSON form (the `surface.json` of a reconstruction).
    fn to_json(&self) -> String {
        self.surface.to_json()
    }

    /// A surface from its JSON form.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        let surface = BSplineSurface::from_json(text)
            .map_err(|e| PyValueError::new_err(format!("not a splineface surface: {e}")))?;
        Ok(BSplineSurfaceHandle::wrap(surface, None))
    }

    fn __repr__(&self) -> String {
        format!(
            "BSplineSurface({} × {} control points, degree ({}, {}), domain u {:?}, v {:?})",
            self.surface.rows(),
            self.surface.cols(),
            self.surface.degree_u(),
            self.surface.degree_v(),
            self.surface.domain_u(),
            self.surface.domain_v()
        )
    }
}

// --- landmarks ----------------------------------------------------------------------------------

/// A face found in an image: the detector's box and score and the model's 68 iBUG points.
#[pyclass(frozen, module = "splineface")]
struct Face {
    /// `(x, y, width, height)`, pixels.
    #[pyo3(get, name = "box")]
    face_box: (i64, i64, i64, i64),
    /// The detector's score (higher is surer).
    #[pyo3(get)]
    score: f64,
    /// How far the model's points on the mirrored image lie from its points on the image, as
    /// a fraction of the outer eye corners' distance (a few percent for a face it is sure of).
    #[pyo3(get)]
    disagreement: f64,
    /// A note when smaller faces were passed over for this one.
    #[pyo3(get)]
    note: Option<String>,
    points: Vec<f64>,
}

#[pymethods]
impl Face {
    /// The 68 iBUG points: float64 `(68, 2)`, pixels, `x` right and `y` down.
    #[getter]
    fn points(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        copied(py, &self.points, &[self.points.len() / 2, 2])
    }

    fn __repr__(&self) -> String {
        let (x, y, w, h) = self.face_box;
        format!("Face(box=({x}, {y}, {w}, {h}), score={:.2})", self.score)
    }
}

impl Face {
    fn new(found: &splineface::detect::LandmarkedFace) -> Self {
        let b = found.face.bbox;
        Face {
            face_box: (b.left, b.top, b.right - b.left + 1, b.bottom - b.top + 1),
            score: found.face.score,
            disagreement: found.disagreement,
            note: found.note.clone(),
            points: found.ibug.iter().flat_map(|p| [p.x, p.y]).collect(),
        }
    }
}

/// dlib's 68-point landmark model, loaded once (the `.dat` or splineface's compact form),
/// with SeetaFace's detector.
#[pyclass(frozen, module = "splineface")]
#[derive(Clone)]
struct Landmarker {
    model: Arc<ShapePredictor>,
    /// The model file.
    path: PathBuf,
    /// Its identity in a batch's fingerprints ([`splineface::batch::file_identity`]): read
    /// when a batch first needs it, not on every load.
    identity: Arc<std::sync::OnceLock<String>>,
}

impl Landmarker {
    /// The model file's identity for a batch's fingerprints, computed once.
    fn identity(&self) -> PyResult<String> {
        if let Some(identity) = self.identity.get() {
            return Ok(identity.clone());
        }
        let identity = splineface::batch::file_identity(Some(&self.path))
            .map_err(|e| SplinefaceError::new_err(e.to_string()))?;
        Ok(self.identity.get_or_init(|| identity).clone())
    }
}

/// An 8-bit image from numpy: `(h, w)` grey or `(h, w, 3)` RGB, uint8.
fn rgb_image(value: &Bound<'_, PyAny>, name: &str) -> PyResult<image::RgbImage> {
    let array = array_of::<u8>(value, name, "uint8")?;
    let dims = array.shape().to_vec();
    let pixels = array.readonly().as_slice()?.to_vec();
    let (h, w) = match dims.as_slice() {
        [h, w] | [h, w, 3] => (*h, *w),
        _ => {
            return Err(PyValueError::new_err(format!(
                "{name}: expected shape (h, w) or (h, w, 3), got {dims:?}"
            )));
        }
    };
    let (Ok(wu), Ok(hu)) = (u32::try_from(w), u32::try_from(h)) else {
        return Err(PyValueError::new_err(format!(
            "{name}: {w} × {h} pixels is too large"
        )));
    };
    if w == 0 || h == 0 {
        return Err(PyValueError::new_err(format!("{name}: the image is empty")));
    }
    let rgb = if dims.len() == 2 {
        pixels.iter().flat_map(|&g| [g, g, g]).collect()
    } else {
        pixels
    };
    image::RgbImage::from_raw(wu, hu, rgb)
        .ok_or_else(|| PyValueError::new_err(format!("{name}: pixel count does not match its shape")))
}

#[pymethods]
impl Landmarker {
    /// Loads the model at `model_path` (dlib's `shape_predictor_68_face_landmarks.dat` or the
    /// compact form of `splineface compact-model`).
    #[new]
    fn new(py: Python<'_>, model_path: PathBuf) -> PyResult<Self> {
        let model = py
            .detach(|| ShapePredictor::read(&model_path))
            .map_err(|e| SplinefaceError::new_err(e.to_string()))?;
        Ok(Landmarker {
            model: Arc::new(model),
            path: model_path,
            identity: Arc::default(),
        })
    }

    /// Every face in `image` (uint8 `(h, w)` or `(h, w, 3)` RGB), largest first, each with its
    /// 68 points.
    fn detect(&self, py: Python<'_>, image: &Bound<'_, PyAny>) -> PyResult<Vec<Face>> {
        let rgb = rgb_image(image, "image")?;
        let found = py.detach(|| {
            let grey = image::DynamicImage::ImageRgb8(rgb.clone()).to_luma8();
            splineface::detect::detect_faces(&grey)
                .into_iter()
                .map(|face| splineface::detect::landmark_face(&self.model, &rgb, face))
                .collect::<Result<Vec<_>, _>>()
        });
        let found = found.map_err(|e| SplinefaceError::new_err(e.to_string()))?;
        Ok(found.iter().map(Face::new).collect())
    }

    /// The subject of a portrait, as `reconstruct` picks it: the largest face, when no other
    /// face rivals it in size.
    ///
    /// Raises `SplinefaceError` with the reason when there is no face or two faces of about
    /// the same size.
    fn subject(&self, py: Python<'_>, image: &Bound<'_, PyAny>) -> PyResult<Face> {
        let rgb = image::DynamicImage::ImageRgb8(rgb_image(image, "image")?);
        let found = py.detach(|| splineface::detect::landmark_subject(&self.model, &rgb));
        found
            .map(|f| Face::new(&f))
            .map_err(|e| SplinefaceError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        format!("Landmarker({} points)", self.model.points())
    }
}

// --- the reconstruction -------------------------------------------------------------------------

/// A finished reconstruction: its arrays, the report, and every output file (`save`).
#[pyclass(frozen, module = "splineface")]
struct Reconstruction {
    files: Vec<(PathBuf, Vec<u8>)>,
    vertices: Vec<f64>,
    triangles: Vec<u32>,
    uv: Vec<f64>,
    texture: Option<(usize, usize, Vec<u8>)>,
    depth: (usize, usize, Vec<f64>),
    structure: Vec<f64>,
    units: String,
    used: Vec<String>,
    skipped: Vec<String>,
}

fn json_file<'py>(py: Python<'py>, files: &[(PathBuf, Vec<u8>)], name: &str) -> PyResult<Bound<'py, PyAny>> {
    let bytes = files
        .iter()
        .find(|(p, _)| p == std::path::Path::new(name))
        .map(|(_, b)| b.as_slice())
        .ok_or_else(|| SplinefaceError::new_err(format!("the reconstruction has no {name}")))?;
    py.import("json")?
        .call_method1("loads", (pyo3::types::PyBytes::new(py, bytes),))
}

#[pymethods]
impl Reconstruction {
    /// Mesh vertices: float64 `(n, 3)`, in `units`.
    #[getter]
    fn vertices(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        copied(py, &self.vertices, &[self.vertices.len() / 3, 3])
    }

    /// Mesh triangles: uint32 `(m, 3)`, counter-clockwise seen from the front.
    #[getter]
    fn triangles(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        copied(py, &self.triangles, &[self.triangles.len() / 3, 3])
    }

    /// Each vertex's surface parameters `(u, v)`, which are its texture coordinates in
    /// `texture`: float64 `(n, 2)`.
    #[getter]
    fn uv(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        copied(py, &self.uv, &[self.uv.len() / 2, 2])
    }

    /// The texture atlas (`face.png`): uint8 `(side, side, 3)`, row 0 at `v = 1`; `None`
    /// for a points-only run.
    #[getter]
    fn texture(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        match &self.texture {
            Some((w, h, pixels)) => Ok(Some(
                to_numpy(py, pixels.clone(), &[*h, *w, 3])?.into_any().unbind(),
            )),
            None => Ok(None),
        }
    }

    /// The depth map (`depth.exr`): float64 `(h, w)`, the face's height toward the viewer in
    /// `units`, top row first, NaN off the face.
    #[getter]
    fn depth(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let (w, h, values) = &self.depth;
        copied(py, values, &[*h, *w])
    }

    /// The 40-point 3D structure: float64 `(40, 3)`, in `units` (`x` right, `y` up, `z`
    /// toward the viewer, origin between the eye centres).
    #[getter]
    fn structure(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        copied(py, &self.structure, &[self.structure.len() / 3, 3])
    }

    /// `mm` or `canonical`.
    #[getter]
    fn units(&self) -> &str {
        &self.units
    }

    /// Each photo the face was made from, as `structure.json` lists them: name, pose
    /// (yaw, pitch, roll in degrees), fit figures.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_file(py, &self.files, "structure.json")?.get_item("photos")
    }

    /// `report.json` as a dict: stages and their times, what was dropped and why, warnings,
    /// the refinement's and the texture's figures.
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_file(py, &self.files, "report.json")
    }

    /// The names of the photos used.
    #[getter]
    fn photos_used(&self) -> Vec<String> {
        self.used.clone()
    }

    /// Each photo skipped before the reconstruction, `path: reason`.
    #[getter]
    fn photos_skipped(&self) -> Vec<String> {
        self.skipped.clone()
    }

    /// The output files' paths, relative to the folder `save` writes.
    #[getter]
    fn files<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        PyList::new(
            py,
            self.files.iter().map(|(p, _)| p.to_string_lossy().into_owned()),
        )
    }

    /// Writes every output file into `directory` (created if needed), as `splineface
    /// reconstruct --out` does: all of them or, on a failure, none changed.
    fn save(&self, py: Python<'_>, directory: PathBuf) -> PyResult<()> {
        py.detach(|| splineface::io::write_into(&directory, &self.files))
            .map_err(|e| SplinefaceError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        format!(
            "Reconstruction({} photos, {} vertices, {} triangles{})",
            self.used.len(),
            self.vertices.len() / 3,
            self.triangles.len() / 3,
            if self.texture.is_some() { ", textured" } else { "" }
        )
    }
}

/// A reference face file ([`ReferenceFace::read`]), or the embedded one.
fn read_reference(path: Option<&std::path::Path>) -> PyResult<ReferenceFace> {
    match path {
        Some(path) => ReferenceFace::read(path).map_err(|e| SplinefaceError::new_err(e.to_string())),
        None => Ok(ReferenceFace::embedded().clone()),
    }
}

/// A keyword setting's reader: stores the value in the settings, or says what it should be.
type Setter = for<'py> fn(&mut Settings, &Bound<'py, PyAny>) -> Result<(), &'static str>;

fn text(v: &Bound<'_, PyAny>) -> Result<String, &'static str> {
    v.extract().map_err(|_| "a string")
}

fn number(v: &Bound<'_, PyAny>) -> Result<f64, &'static str> {
    v.extract().map_err(|_| "a number")
}

fn flag(v: &Bound<'_, PyAny>) -> Result<bool, &'static str> {
    v.extract().map_err(|_| "True or False")
}

fn count(v: &Bound<'_, PyAny>) -> Result<usize, &'static str> {
    v.extract().map_err(|_| "a whole number, 0 or more")
}

/// `reconstruct`'s keyword settings (those of [`splineface::pipeline::Settings`], the command
/// line's flags), each with its reader; the refusal of an unknown keyword lists them from here.
const SETTINGS: &[(&str, Setter)] = &[
    ("units", |s, v| {
        s.units = text(v)?;
        Ok(())
    }),
    ("eye_distance", |s, v| {
        s.eye_distance = number(v)?;
        Ok(())
    }),
    ("shape", |s, v| {
        s.shape = text(v)?;
        Ok(())
    }),
    ("space_noise", |s, v| {
        s.space_noise = number(v)?;
        Ok(())
    }),
    ("expression_sigma", |s, v| {
        s.expression_sigma = number(v)?;
        Ok(())
    }),
    ("expressions", |s, v| {
        s.expressions = flag(v)?;
        Ok(())
    }),
    ("outline", |s, v| {
        s.outline = flag(v)?;
        Ok(())
    }),
    ("lips", |s, v| {
        s.lips = flag(v)?;
        Ok(())
    }),
    ("refine", |s, v| {
        s.refine = flag(v)?;
        Ok(())
    }),
    ("displacement", |s, v| {
        s.displacement = flag(v)?;
        Ok(())
    }),
    ("deformation", |s, v| {
        s.deformation = text(v)?;
        Ok(())
    }),
    ("spacing", |s, v| {
        s.spacing = number(v)?;
        Ok(())
    }),
    ("depth_size", |s, v| {
        s.depth_size = count(v)?;
        Ok(())
    }),
    ("texture_size", |s, v| {
        s.texture_size = if v.is_none() {
            None
        } else {
            Some(u32::try_from(count(v)?).map_err(|_| "at most 8192")?)
        };
        Ok(())
    }),
    ("min_photos", |s, v| {
        s.min_photos = count(v)?;
        Ok(())
    }),
];

/// The pipeline's options from `reconstruct`'s keyword settings ([`SETTINGS`]), unknown
/// keywords refused.
fn options_of(settings: Option<&Bound<'_, PyDict>>) -> PyResult<splineface::pipeline::PipelineOptions> {
    let mut s = Settings::default();
    for (key, value) in settings.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        let Some((_, set)) = SETTINGS.iter().find(|(name, _)| *name == key) else {
            let names: Vec<&str> = SETTINGS.iter().map(|(name, _)| *name).collect();
            return Err(PyTypeError::new_err(format!(
                "unexpected keyword argument '{key}' (the settings are {})",
                names.join(", ")
            )));
        };
        set(&mut s, &value).map_err(|what| PyTypeError::new_err(format!("{key}: expected {what}")))?;
    }
    s.options().map_err(|e| setting_error(&e))
}

/// Where `reconstruct`'s landmarks come from: a model path (loaded here) or a loaded
/// `Landmarker`.
fn model_of(value: Option<&Bound<'_, PyAny>>, py: Python<'_>) -> PyResult<Option<Landmarker>> {
    let Some(value) = value else { return Ok(None) };
    if value.is_none() {
        return Ok(None);
    }
    if let Ok(landmarker) = value.cast::<Landmarker>() {
        return Ok(Some(landmarker.get().clone()));
    }
    let path: PathBuf = value
        .extract()
        .map_err(|_| PyTypeError::new_err("landmark_model: a path or a splineface.Landmarker"))?;
    Landmarker::new(py, path).map(Some)
}

/// The photo paths of `photos`: a folder, one path, or a sequence of paths.
fn photo_paths(photos: Option<&Bound<'_, PyAny>>) -> PyResult<Vec<PathBuf>> {
    let Some(photos) = photos else {
        return Ok(Vec::new());
    };
    if photos.is_none() {
        return Ok(Vec::new());
    }
    let listed = if let Ok(one) = photos.extract::<PathBuf>() {
        if one.is_dir() {
            splineface::pipeline::photo_list(&[], Some(&one))
        } else {
            splineface::pipeline::photo_list(&[one], None)
        }
    } else {
        let many: Vec<PathBuf> = photos
            .extract()
            .map_err(|_| PyTypeError::new_err("photos: a folder, a path or a list of paths"))?;
        splineface::pipeline::photo_list(&many, None)
    };
    listed.map_err(|e| SplinefaceError::new_err(e.to_string()))
}

/// Reconstructs a face, as `splineface reconstruct` does: see the package's documentation.
#[pyfunction]
#[pyo3(signature = (photos = None, landmarks = None, landmark_model = None, reference = None, *, expression_of = None, **settings))]
fn reconstruct(
    py: Python<'_>,
    photos: Option<&Bound<'_, PyAny>>,
    landmarks: Option<PathBuf>,
    landmark_model: Option<&Bound<'_, PyAny>>,
    reference: Option<PathBuf>,
    expression_of: Option<String>,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<Reconstruction> {
    let mut options = options_of(settings)?;
    let photos = photo_paths(photos)?;
    if let Some(dir) = &landmarks
        && !dir.is_dir()
    {
        return Err(SplinefaceError::new_err(format!(
            "landmarks: {} is not a folder",
            dir.display()
        )));
    }
    let model_start = std::time::Instant::now();
    let model = model_of(landmark_model, py)?.map(|landmarker| landmarker.model);
    let model_seconds = model.as_ref().map(|_| model_start.elapsed().as_secs_f64());
    let reference = read_reference(reference.as_deref())?;
    let error = |e: &dyn std::fmt::Display| SplinefaceError::new_err(e.to_string());
    type Built = (
        PhotoSet,
        splineface::pipeline::Reconstruction,
        Vec<(PathBuf, Vec<u8>)>,
    );
    let built = py.detach(|| -> Result<Built, PyErr> {
        let set = splineface::pipeline::gather_inputs(&photos, landmarks.as_deref(), model.as_deref())
            .map_err(|e| error(&e))?;
        set.check_count(options.min_photos).map_err(|e| error(&e))?;
        if let Some(name) = &expression_of {
            let index = splineface::pipeline::photo_index(&set.inputs, name)
                .map_err(|why| PyValueError::new_err(format!("expression_of={name}: {why}")))?;
            options.expression_of = Some(index);
        }
        let result = splineface::pipeline::reconstruct(&set.inputs, &reference, &options, |_| {})
            .map_err(|e| error(&e))?;
        let files = set.files(&result, model_seconds).map_err(|e| error(&e))?;
        Ok((set, result, files))
    })?;
    let (set, result, files) = built;
    let mesh = result.output_mesh();
    let uv = mesh
        .texture()
        .map(|t| t.uvs.iter().flat_map(|p| [p.x, p.y]).collect())
        .unwrap_or_default();
    let map = result
        .depth_map()
        .map_err(|e| SplinefaceError::new_err(e.to_string()))?;
    let (w, h) = (map.raster.width, map.raster.height);
    // The library's rows run from the bottom; numpy images from the top.
    let depth: Vec<f64> = (0..h)
        .rev()
        .flat_map(|r| map.heights[r * w..(r + 1) * w].to_vec())
        .collect();
    Ok(Reconstruction {
        vertices: mesh.positions().iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        triangles: mesh.triangles().iter().flatten().copied().collect(),
        uv,
        texture: result.texture.as_ref().map(|t| {
            (
                t.atlas.width() as usize,
                t.atlas.height() as usize,
                t.atlas.as_raw().clone(),
            )
        }),
        depth: (w, h, depth),
        structure: result.structure().iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        units: match result.options.units {
            splineface::face::Units::Canonical => "canonical",
            _ => "mm",
        }
        .to_owned(),
        used: result.depth.photos.iter().map(|p| p.name.clone()).collect(),
        skipped: set.skipped,
        files,
    })
}

/// Photographs the embedded demo subject (a face fitted to an ICT-FaceKit identity) with
/// splineface's renderer under `photos` poses and writes the photos and their landmark files
/// (`NAME.png`, `NAME.pts`, landmark `noise` in % of the eye distance) into `directory`: inputs
/// for `reconstruct(photos=directory, landmarks=directory)` that need no landmark model.
/// Returns the files' names.
#[pyfunction]
#[pyo3(signature = (directory, photos = 12, noise = 1.0, seed = 2016))]
fn write_demo_photos(
    py: Python<'_>,
    directory: PathBuf,
    photos: usize,
    noise: f64,
    seed: u64,
) -> PyResult<Vec<String>> {
    let files = py.detach(|| -> Result<Vec<(PathBuf, Vec<u8>)>, splineface::Error> {
        let scene = splineface::demo::scene(&splineface::demo::SceneOptions {
            photos,
            noise: noise / 100.0,
            seed,
            ..splineface::demo::SceneOptions::default()
        })?;
        let files = scene.files()?;
        splineface::io::write_into(&directory, &files)?;
        Ok(files)
    });
    let files = files.map_err(library_error)?;
    Ok(files
        .iter()
        .map(|(p, _)| p.to_string_lossy().into_owned())
        .collect())
}

/// A batch row as a dict (the `summary.jsonl` form).
fn row_to_python<'py>(py: Python<'py>, row: &splineface::batch::SubjectRow) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(row).map_err(|e| SplinefaceError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// Reconstructs one subject of a batch, as `splineface batch` does: the photos and/or landmark
/// files in `folder` to `out/NAME` (`NAME` the folder's name), skipped when its outputs are up
/// to date. Returns the subject's summary row (a dict); a failure is a row with status
/// `failed` and its message, never an exception. The keywords are `reconstruct`'s.
#[pyfunction]
#[pyo3(signature = (folder, out, landmark_model = None, reference = None, *, force = false, **settings))]
fn reconstruct_subject<'py>(
    py: Python<'py>,
    folder: PathBuf,
    out: PathBuf,
    landmark_model: Option<&Bound<'py, PyAny>>,
    reference: Option<PathBuf>,
    force: bool,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let options = options_of(settings)?;
    let Some(name) = folder.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Err(SplinefaceError::new_err(format!(
            "{}: not a subject folder",
            folder.display()
        )));
    };
    if !folder.is_dir() {
        return Err(SplinefaceError::new_err(format!(
            "{}: not a folder",
            folder.display()
        )));
    }
    let (model, model_identity) = match model_of(landmark_model, py)? {
        Some(landmarker) => (Some(landmarker.model.clone()), landmarker.identity()?),
        None => (None, "none".to_owned()),
    };
    let reference_identity = splineface::batch::file_identity(reference.as_deref())
        .map_err(|e| SplinefaceError::new_err(e.to_string()))?;
    let reference = read_reference(reference.as_deref())?;
    let subject = splineface::batch::Subject { name, folder };
    let row = py.detach(|| {
        let job = splineface::batch::BatchJob {
            model: model.as_deref(),
            model_identity,
            reference: &reference,
            reference_identity,
            options,
            force,
        };
        splineface::batch::run_subject(&subject, &out, &job)
    });
    row_to_python(py, &row)
}

/// The subject folders of a batch root (its sub-folders, by name), checked as `splineface
/// batch` checks them: `root` must hold some, and `out`, when given, must lie outside `root`
/// and be writable.
#[pyfunction]
#[pyo3(signature = (root, out = None))]
fn batch_subjects(root: PathBuf, out: Option<PathBuf>) -> PyResult<Vec<PathBuf>> {
    let error = |e: splineface::batch::BatchError| SplinefaceError::new_err(e.to_string());
    let subjects = splineface::batch::subjects(&root).map_err(error)?;
    if let Some(out) = out {
        splineface::batch::check_output(&root, &out).map_err(error)?;
    }
    Ok(subjects.into_iter().map(|s| s.folder).collect())
}

/// Writes `summary.csv` and `summary.jsonl` into `out` from rows (the dicts
/// `reconstruct_subject` returns, in any order: sorted by subject), as `splineface batch`
/// writes them.
#[pyfunction]
fn write_summary(py: Python<'_>, out: PathBuf, rows: &Bound<'_, PyList>) -> PyResult<()> {
    let json = py.import("json")?;
    let mut parsed = Vec::with_capacity(rows.len());
    for (k, row) in rows.iter().enumerate() {
        let text: String = json.call_method1("dumps", (row,))?.extract()?;
        let row: splineface::batch::SubjectRow = serde_json::from_str(&text)
            .map_err(|e| PyValueError::new_err(format!("rows[{k}]: not a subject row: {e}")))?;
        parsed.push(row);
    }
    parsed.sort_by(|a, b| a.subject.cmp(&b.subject));
    py.detach(|| splineface::batch::write_summary(&out, &parsed))
        .map_err(|e| SplinefaceError::new_err(e.to_string()))
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SplinefaceError", m.py().get_type::<SplinefaceError>())?;
    m.add_class::<BSplineSurfaceHandle>()?;
    m.add_class::<Face>()?;
    m.add_class::<Landmarker>()?;
    m.add_class::<Reconstruction>()?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(write_demo_photos, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct_subject, m)?)?;
    m.add_function(wrap_pyfunction!(write_summary, m)?)?;
    m.add_function(wrap_pyfunction!(batch_subjects, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
