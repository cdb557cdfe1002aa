//! RASL: robust batch alignment of the photos (and their mirror images) by sparse and low-rank
//! decomposition (Peng, Ganesh, Wright, Xu & Ma, CVPR 2010 / TPAMI 2012), and the frontal
//! structure it gives (`../METHOD.md` §2).
//!
//! # The method
//!
//! Each image `Iᵢ` gets an affine warp `τᵢ` from a canonical window (`width × height` pixels,
//! `y` down) into the image; `Iᵢ ∘ τᵢ` samples the image at `τᵢ(x)` for every window pixel `x`.
//! With `D∘τ = [vec(I₁∘τ₁)/‖·‖ … vec(Iₙ∘τₙ)/‖·‖]` (each column normalised), RASL solves
//!
//! ```text
//! min ‖A‖_* + λ‖E‖₁   subject to   D∘τ = A + E,      λ = λ_c / √d  (d = window pixels)
//! ```
//!
//! by linearising the warps in an outer loop, `D∘(τ + Δτ) ≈ D∘τ + Σᵢ Jᵢ Δτᵢ eᵢᵀ` with `Jᵢ` the
//! Jacobian of the normalised warped image in the 6 affine parameters, and solving the convex
//! problem in `A, E, Δτ` by an inexact augmented Lagrangian (singular-value thresholding for
//! `A`, soft thresholding for `E`, least squares for `Δτ` through the QR factors of `Jᵢ`),
//! with RASL's settings: `μ₀ = 1.25/‖D‖₂`, `ρ = 1.25`, inner tolerance `10⁻⁷`; the outer loop
//! stops when the objective improves by less than the outer tolerance (relative, `10⁻²`).
//!
//! # Choices
//!
//! * **Singular values through the Gram matrix.** The inner loop's cost is the SVD of a
//!   `d × n` matrix (`12,000 × 70` for 35 photos at 120 × 100). Its thresholding needs only
//!   `T·V·diag(max(σ − 1/μ, 0)/σ)·Vᵀ`, and `V`, `σ` come from the eigen-decomposition of the
//!   `n × n` Gram matrix `TᵀT`: two `d × n × n` products, in `f32` (images carry 8 bits). The
//!   Gram route squares the condition number, which only blurs singular values far below the
//!   threshold: a test checks the result against a full SVD.
//! * **No drift to a point.** Affine RASL can lower its objective by shrinking every warp
//!   toward a small, smooth patch. After each outer step the warps are composed on the window
//!   side with the one affine map that restores their *mean* to its starting value: the batch
//!   keeps its average framing (set by the eye and mouth points), and only the warps' differences
//!   are learnt.
//! * **Start.** `τᵢ` starts as the similarity that puts the photo's eye centres and mouth centre
//!   (mean of the 8 mouth points) at fixed places of the window, in the least-squares sense.
//!
//! The frontal structure is the mean of the warped points (eq. 4), `τᵢ⁻¹(Sᵢ)` over originals
//! and mirrors, moved into the canonical plane (eye centres at `(±25, 0)`, `y` up) by a
//! similarity.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, Point2, Vector2};
use rayon::prelude::*;

use super::image::{GreyImage, PhotoProblem};
use super::{AlignError, FrontalMethod, FrontalStructure, PhotoPoints, apply_affine};
use crate::Real;
use crate::structure::{self, LEFT_EYE_CENTRE, POINT_COUNT, RIGHT_EYE_CENTRE};

/// RASL's settings (defaults from the paper and the RASL code).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaslOptions {
    /// Window width, pixels (100).
    pub width: usize,
    /// Window height, pixels (120).
    pub height: usize,
    /// `λ_c` of `λ = λ_c/√d` (1).
    pub lambda_c: Real,
    /// Outer loop: stop when the objective improves by less than this, relative (10⁻²).
    pub outer_tolerance: Real,
    /// Inner loop: stop when `‖D + JΔτ − A − E‖_F / ‖D‖_F` is below this (10⁻⁷).
    pub inner_tolerance: Real,
    /// Outer iterations at most (50).
    pub max_outer: usize,
    /// Inner iterations at most per outer iteration (1000).
    pub max_inner: usize,
}

impl Default for RaslOptions {
    fn default() -> Self {
        RaslOptions {
            width: 100,
            height: 120,
            lambda_c: 1.0,
            outer_tolerance: 1e-2,
            inner_tolerance: 1e-7,
            max_outer: 50,
            max_inner: 1000,
        }
    }
}

/// One photo for RASL: its grey image and its points.
#[derive(Debug, Clone)]
pub struct RaslPhoto {
    /// The image.
    pub image: GreyImage,
    /// Its 40 points, in its pixels.
    pub points: PhotoPoints,
}

/// A photo left out of the batch, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    /// The photo's name.
    pub name: String,
    /// Why.
    pub reason: String,
}

/// What RASL found.
#[derive(Debug, Clone)]
pub struct RaslResult {
    /// The frontal structure, for the depth stage; `warps` are per *kept* photo, in input order.
    pub frontal: FrontalStructure,
    /// The names of the photos kept, in input order.
    pub kept: Vec<String>,
    /// Photos left out, and why.
    pub dropped: Vec<Dropped>,
    /// The final warps `τ` (window → image pixels), two per kept photo: photo, then mirror.
    pub warps: Vec<Matrix2x3<Real>>,
    /// The starting warps, likewise.
    pub initial_warps: Vec<Matrix2x3<Real>>,
    /// The warped images at the start and at the end (columns, not normalised, `d × 2n`).
    pub before: DMatrix<f32>,
    /// As `before`, after alignment.
    pub after: DMatrix<f32>,
    /// The low-rank part `A` (normalised columns).
    pub low_rank: DMatrix<f32>,
    /// The sparse part `E`.
    pub sparse: DMatrix<f32>,
    /// The objective `‖A‖_* + λ‖E‖₁` after each outer iteration.
    pub objective: Vec<Real>,
    /// Inner iterations (singular-value thresholdings) run in all.
    pub inner_iterations: usize,
    /// The options used.
    pub options: RaslOptions,
}

/// A column of the batch: an image (shared with its gradients) and its points.
struct Column {
    image: GreyImage,
    gx: Vec<f32>,
    gy: Vec<f32>,
    points: Vec<Point2<Real>>,
}

/// Where the eye centres and the mouth centre go in the window.
fn canonical_anchors(width: usize, height: usize) -> [Point2<Real>; 3] {
    let (w, h) = (width as Real, height as Real);
    [
        Point2::new(0.3 * w, 0.38 * h),
        Point2::new(0.7 * w, 0.38 * h),
        Point2::new(0.5 * w, 0.78 * h),
    ]
}

fn anchors(points: &[Point2<Real>]) -> [Point2<Real>; 3] {
    let mouth = (32..40).fold(Vector2::zeros(), |s, k| s + points[k].coords) / 8.0;
    [
        points[RIGHT_EYE_CENTRE],
        points[LEFT_EYE_CENTRE],
        Point2::from(mouth),
    ]
}

/// The least-squares similarity (no reflection) taking `from` onto `to`, as `[A | t]`.
fn similarity(from: &[Point2<Real>], to: &[Point2<Real>]) -> Matrix2x3<Real> {
    let n = from.len() as Real;
    let cf = from.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n;
    let ct = to.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n;
    let (mut a, mut b, mut norm) = (0.0, 0.0, 0.0);
    for (p, q) in from.iter().zip(to) {
        let (x, y) = (p.coords - cf, q.coords - ct);
        a += x.dot(&y);
        b += x.x * y.y - x.y * y.x;
        norm += x.norm_squared();
    }
    let (c, s) = (a / norm, b / norm);
    let linear = Matrix2::new(c, -s, s, c);
    let t = ct - linear * cf;
    Matrix2x3::new(c, -s, t.x, s, c, t.y)
}

fn to_matrix3(m: &Matrix2x3<Real>) -> Matrix3<Real> {
    Matrix3::new(
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        0.0,
        0.0,
        1.0,
    )
}

fn from_matrix3(m: &Matrix3<Real>) -> Matrix2x3<Real> {
    m.fixed_view::<2, 3>(0, 0).into_owned()
}

/// Checks a photo for RASL.
fn check(photo: &RaslPhoto) -> Result<(), String> {
    photo.points.validate().map_err(|e| e.to_string())?;
    let (w, h) = (photo.image.width(), photo.image.height());
    for (k, p) in photo.points.points.iter().enumerate() {
        if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= (w - 1) as Real && p.y <= (h - 1) as Real) {
            return Err(PhotoProblem::PointOutside {
                point: k,
                x: p.x,
                y: p.y,
                width: w,
                height: h,
            }
            .to_string());
        }
    }
    Ok(())
}

impl Column {
    fn new(image: GreyImage, points: Vec<Point2<Real>>) -> Self {
        let (gx, gy) = image.gradients();
        Column {
            image,
            gx,
            gy,
            points,
        }
    }

    /// The warped image (not normalised) and, with `jacobian`, its `d × 6` derivative in the
    /// affine parameters `[a11 a12 a13 a21 a22 a23]`.
    fn warp(
        &self,
        tau: &Matrix2x3<Real>,
        width: usize,
        height: usize,
        jacobian: bool,
    ) -> (Vec<f32>, Option<DMatrix<f32>>) {
        let d = width * height;
        let mut values = Vec::with_capacity(d);
        let mut j = jacobian.then(|| DMatrix::<f32>::zeros(d, 6));
        // Column-major vectorisation: pixel (x, y) is entry x·height + y.
        for x in 0..width {
            for y in 0..height {
                let (xf, yf) = (x as Real, y as Real);
                let u = tau[(0, 0)] * xf + tau[(0, 1)] * yf + tau[(0, 2)];
                let v = tau[(1, 0)] * xf + tau[(1, 1)] * yf + tau[(1, 2)];
                values.push(self.image.sample(self.image.data(), u, v));
                if let Some(j) = j.as_mut() {
                    let r = x * height + y;
                    let (ix, iy) = (
                        self.image.sample(&self.gx, u, v),
                        self.image.sample(&self.gy, u, v),
                    );
                    let (xf, yf) = (xf as f32, yf as f32);
                    j[(r, 0)] = ix * xf;
                    j[(r, 1)] = ix * yf;
                    j[(r, 2)] = ix;
                    j[(r, 3)] = iy * xf;
                    j[(r, 4)] = iy * yf;
                    j[(r, 5)] = iy;
                }
            }
        }
        (values, j)
    }
}

/// Singular-value thresholding of `t` at `threshold` through the Gram matrix (see the module
/// documentation): returns `U·max(Σ − threshold, 0)·Vᵀ`, the nuclear norm of the result, and
/// the largest singular value of `t`.
pub fn singular_value_threshold(t: &DMatrix<f32>, threshold: Real) -> (DMatrix<f32>, Real, Real) {
    let gram32 = t.tr_mul(t);
    let gram: DMatrix<Real> = gram32.map(Real::from);
    let eigen = gram.symmetric_eigen();
    let n = t.ncols();
    let mut weights = DMatrix::<Real>::zeros(n, n);
    let mut nuclear = 0.0;
    let mut largest: Real = 0.0;
    for k in 0..n {
        let sigma = eigen.eigenvalues[k].max(0.0).sqrt();
        largest = largest.max(sigma);
        let kept = sigma - threshold;
        if kept > 0.0 {
            nuclear += kept;
            let v = eigen.eigenvectors.column(k);
            weights += (v * v.transpose()) * (kept / sigma);
        }
    }
    let weights32 = weights.map(|x| x as f32);
    (t * weights32, nuclear, largest)
}

fn soft_threshold(x: f32, threshold: f32) -> f32 {
    if x > threshold {
        x - threshold
    } else if x < -threshold {
        x + threshold
    } else {
        0.0
    }
}

/// Aligns the photos (and their mirror images) by RASL and returns the frontal structure
/// (see the module documentation). Photos whose points are unusable or lie outside their
/// image are left out and listed in [`RaslResult::dropped`].
///
/// # Errors
/// [`AlignError::NoPhotos`] for an empty batch, [`AlignError::Frontal`] when no photo is
/// usable (saying why each was dropped) or an option is out of range.
pub fn rasl_frontal(photos: &[RaslPhoto], options: &RaslOptions) -> Result<RaslResult, AlignError> {
    if photos.is_empty() {
        return Err(AlignError::NoPhotos);
    }
    let bad_option = |what: String| AlignError::Frontal { problem: what };
    if !(16..=1024).contains(&options.width) || !(16..=1024).contains(&options.height) {
        return Err(bad_option(format!(
            "RASL window {}×{}: each side must be between 16 and 1024",
            options.width, options.height
        )));
    }
    for (name, value) in [
        ("lambda_c", options.lambda_c),
        ("outer_tolerance", options.outer_tolerance),
        ("inner_tolerance", options.inner_tolerance),
    ] {
        if !(value > 0.0 && value.is_finite()) {
            return Err(bad_option(format!(
                "RASL option {name} = {value} must be positive"
            )));
        }
    }
    if options.max_outer == 0 || options.max_inner == 0 {
        return Err(bad_option("RASL iteration caps must be at least 1".into()));
    }
    let mut dropped = Vec::new();
    let mut kept = Vec::new();
    let mut columns = Vec::new();
    for photo in photos {
        match check(photo) {
            Err(reason) => dropped.push(Dropped {
                name: photo.points.name.clone(),
                reason,
            }),
            Ok(()) => {
                kept.push(photo.points.name.clone());
                let w = (photo.image.width() - 1) as Real;
                let mirrored_points: Vec<Point2<Real>> = structure::POINTS
                    .iter()
                    .map(|def| {
                        let p = photo.points.points[def.mirror];
                        Point2::new(w - p.x, p.y)
                    })
                    .collect();
                columns.push(Column::new(photo.image.clone(), photo.points.points.clone()));
                columns.push(Column::new(photo.image.mirrored(), mirrored_points));
            }
        }
    }
    if columns.is_empty() {
        let reasons: Vec<String> = dropped
            .iter()
            .map(|d| format!("{}: {}", d.name, d.reason))
            .collect();
        return Err(bad_option(format!("no usable photo ({})", reasons.join("; "))));
    }

    let (width, height) = (options.width, options.height);
    let d = width * height;
    let n = columns.len();
    let lambda = options.lambda_c / (d as Real).sqrt();
    let window_anchors = canonical_anchors(width, height);
    let initial: Vec<Matrix2x3<Real>> = columns
        .iter()
        .map(|c| similarity(&window_anchors, &anchors(&c.points)))
        .collect();
    let mean_of =
        |warps: &[Matrix2x3<Real>]| warps.iter().fold(Matrix2x3::zeros(), |s, w| s + w) / warps.len() as Real;
    let initial_mean = mean_of(&initial);
    let mut warps = initial.clone();

    let before = warped_matrix(&columns, &warps, width, height);
    let mut objective = Vec::new();
    let mut inner_total = 0;
    let mut low_rank = DMatrix::<f32>::zeros(d, n);
    let mut sparse = DMatrix::<f32>::zeros(d, n);
    let mut previous = Real::INFINITY;
    for _ in 0..options.max_outer {
        // Warp, normalise, differentiate, factor.
        let prepared: Vec<(Vec<f32>, DMatrix<f32>, DMatrix<f32>)> = columns
            .par_iter()
            .zip(&warps)
            .map(|(column, tau)| {
                let (values, jacobian) = column.warp(tau, width, height, true);
                let jacobian = jacobian.expect("asked for");
                let norm = values
                    .iter()
                    .map(|v| v * v)
                    .sum::<f32>()
                    .sqrt()
                    .max(f32::MIN_POSITIVE);
                let y: Vec<f32> = values.iter().map(|v| v / norm).collect();
                let yv = DVector::from_column_slice(&y);
                // J = (I − ỹỹᵀ) ∂y/∂p / ‖y‖
                let projected = (&jacobian - &yv * (yv.transpose() * &jacobian)) / norm;
                let qr = projected.map(Real::from).qr();
                (y, qr.q().map(|x| x as f32), qr.r().map(|x| x as f32))
            })
            .collect();
        let mut data = DMatrix::<f32>::zeros(d, n);
        for (k, (y, _, _)) in prepared.iter().enumerate() {
            data.column_mut(k).copy_from_slice(y);
        }
        let (a, e, delta, inner, value) = inner_loop(&data, &prepared, lambda, options);
        inner_total += inner;
        low_rank = a;
        sparse = e;
        for (k, warp) in warps.iter_mut().enumerate() {
            let r = &prepared[k].2;
            let step = r
                .map(Real::from)
                .solve_upper_triangular(&delta[k])
                .unwrap_or_else(|| DVector::zeros(6));
            for p in 0..6 {
                warp[(p / 3, p % 3)] += step[p];
            }
        }
        // Restore the mean warp: τᵢ ← τᵢ ∘ G with mean(τ ∘ G) = mean(τ⁰).
        let mean = mean_of(&warps);
        let (mean_linear, start_linear) = (
            mean.fixed_view::<2, 2>(0, 0).into_owned(),
            initial_mean.fixed_view::<2, 2>(0, 0).into_owned(),
        );
        if let Some(inverse) = mean_linear.try_inverse() {
            let g_linear = inverse * start_linear;
            let g_shift = inverse * (initial_mean.column(2) - mean.column(2));
            let g = Matrix3::new(
                g_linear[(0, 0)],
                g_linear[(0, 1)],
                g_shift.x,
                g_linear[(1, 0)],
                g_linear[(1, 1)],
                g_shift.y,
                0.0,
                0.0,
                1.0,
            );
            for warp in warps.iter_mut() {
                *warp = from_matrix3(&(to_matrix3(warp) * g));
            }
        }
        objective.push(value);
        let improved = previous - value;
        previous = value;
        if improved.abs() < options.outer_tolerance * value.abs() {
            break;
        }
    }
    let after = warped_matrix(&columns, &warps, width, height);

    // The frontal structure: the mean of τᵢ⁻¹(Sᵢ), in window pixels (y down), then unified.
    let inverses: Vec<Matrix3<Real>> = warps
        .iter()
        .map(|w| to_matrix3(w).try_inverse().unwrap_or_else(Matrix3::identity))
        .collect();
    let in_window: Vec<Vec<Point2<Real>>> = columns
        .iter()
        .zip(&inverses)
        .map(|(c, inv)| {
            c.points
                .iter()
                .map(|p| apply_affine(&from_matrix3(inv), p))
                .collect()
        })
        .collect();
    let mean: Vec<Point2<Real>> = (0..POINT_COUNT)
        .map(|k| Point2::from(in_window.iter().fold(Vector2::zeros(), |s, ps| s + ps[k].coords) / n as Real))
        .collect();
    // Window (y down) → y up, then the similarity that puts the eye centres at (±25, 0).
    let flipped: Vec<Point2<Real>> = mean.iter().map(|p| Point2::new(p.x, -p.y)).collect();
    let (unifying, frontal_points) =
        structure::unify_2d(&flipped).map_err(|e| bad_option(format!("the aligned structure: {e}")))?;
    let window_to_canonical =
        unifying.to_homogeneous() * Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
    // A kept photo's warp in FrontalStructure maps its y-up points (x, −v) to the plane.
    let flip = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
    let mut photo_warps = Vec::with_capacity(n / 2);
    let mut mirror_warps = Vec::with_capacity(n / 2);
    for (k, inv) in inverses.iter().enumerate() {
        if k % 2 == 0 {
            photo_warps.push(from_matrix3(&(window_to_canonical * inv * flip)));
        } else {
            // The mirror's pixels are (w − 1 − x, y) of the photo's; PhotoPoints::mirrored_y_up
            // gives (−x, −y): x ↦ w − 1 + x′ for x′ = −x.
            let w = (columns[k].image.width() - 1) as Real;
            let unmirror = Matrix3::new(1.0, 0.0, w, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
            mirror_warps.push(from_matrix3(&(window_to_canonical * inv * unmirror)));
        }
    }
    let mut residual = 0.0;
    for ps in &in_window {
        for (k, p) in ps.iter().enumerate() {
            let q = from_matrix3(&window_to_canonical);
            residual += (apply_affine(&q, p) - frontal_points[k]).norm_squared();
        }
    }
    let residual_rms = (residual / (n * POINT_COUNT) as Real).sqrt();
    Ok(RaslResult {
        frontal: FrontalStructure {
            points: frontal_points,
            warps: photo_warps,
            mirror_warps,
            residual_rms,
            method: FrontalMethod::Rasl,
        },
        kept,
        dropped,
        warps,
        initial_warps: initial,
        before,
        after,
        low_rank,
        sparse,
        objective,
        inner_iterations: inner_total,
        options: *options,
    })
}

fn warped_matrix(columns: &[Column], warps: &[Matrix2x3<Real>], width: usize, height: usize) -> DMatrix<f32> {
    let mut m = DMatrix::<f32>::zeros(width * height, columns.len());
    let warped: Vec<Vec<f32>> = columns
        .par_iter()
        .zip(warps)
        .map(|(c, w)| c.warp(w, width, height, false).0)
        .collect();
    for (k, values) in warped.iter().enumerate() {
        m.column_mut(k).copy_from_slice(values);
    }
    m
}

type Prepared = (Vec<f32>, DMatrix<f32>, DMatrix<f32>);

/// The inner augmented-Lagrange loop: returns `A`, `E`, the steps `δᵢ` (in the `Qᵢ` basis),
/// the iterations run and the objective `‖A‖_* + λ‖E‖₁`.
fn inner_loop(
    data: &DMatrix<f32>,
    prepared: &[Prepared],
    lambda: Real,
    options: &RaslOptions,
) -> (DMatrix<f32>, DMatrix<f32>, Vec<DVector<Real>>, usize, Real) {
    let (d, n) = data.shape();
    let (_, _, two_norm) = singular_value_threshold(data, Real::INFINITY);
    let inf_norm = data.iter().fold(0.0f32, |m, v| m.max(v.abs())) as Real / lambda;
    let dual = two_norm.max(inf_norm);
    let mut y = data.map(|v| v / dual as f32);
    let mut mu = 1.25 / two_norm;
    let rho = 1.25;
    let data_norm = data.norm() as Real;
    let mut e = DMatrix::<f32>::zeros(d, n);
    let mut a = DMatrix::<f32>::zeros(d, n);
    let mut dt = DMatrix::<f32>::zeros(d, n);
    let mut delta: Vec<DVector<Real>> = vec![DVector::zeros(6); n];
    let mut nuclear = 0.0;
    let mut iterations = 0;
    for _ in 0..options.max_inner {
        iterations += 1;
        let inv_mu = (1.0 / mu) as f32;
        // A: singular-value thresholding of D + JΔτ − E + Y/μ.
        let mut t = data + &dt - &e;
        t.zip_apply(&y, |t, y| *t += y * inv_mu);
        let (low, norm, _) = singular_value_threshold(&t, 1.0 / mu);
        a = low;
        nuclear = norm;
        // E: soft thresholding of D + JΔτ − A + Y/μ.
        let shrink = (lambda / mu) as f32;
        e = data + &dt - &a;
        e.zip_apply(&y, |e, y| *e = soft_threshold(*e + y * inv_mu, shrink));
        // Δτ: least squares per column against A + E − D − Y/μ.
        let mut target = &a + &e - data;
        target.zip_apply(&y, |t, y| *t -= y * inv_mu);
        for k in 0..n {
            let q = &prepared[k].1;
            let step = q.tr_mul(&target.column(k));
            delta[k] = step.map(Real::from);
            dt.set_column(k, &(q * step));
        }
        // Residual and multipliers.
        let mut z = data + &dt - &a - &e;
        let residual = z.norm() as Real / data_norm;
        z *= mu as f32;
        y += &z;
        mu *= rho;
        if residual < options.inner_tolerance {
            break;
        }
    }
    let l1: Real = e.iter().map(|v| Real::from(v.abs())).sum();
    (a, e, delta, iterations, nuclear + lambda * l1)
}
