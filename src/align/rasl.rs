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

use nalgebra::{DMatrix, Matrix2, Matrix2x3, Matrix3, Point2, Vector2};
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
    /// The inner loop's growth factor of the penalty `μ`: 1.5 (RASL's is 1.25; see
    /// [`RaslOptions::default`]).
    pub rho: Real,
    /// Outer iterations at most (50).
    pub max_outer: usize,
    /// Inner iterations at most per outer iteration (1000).
    pub max_inner: usize,
}

impl Default for RaslOptions {
    /// RASL's settings, except `ρ = 1.5` instead of 1.25, chosen by measurement
    /// (`cargo run --release --example rasl_eval`): on 35 photos under varied poses it needs
    /// 172 inner iterations instead of 307 (1.3 s instead of 2.4 s), and the frontal structure's
    /// distance from the true frontal changes by 0.003 units (1.653 against 1.650); on a batch
    /// of warped copies the worst landmark disagreement after alignment is 0.010 px instead of
    /// 0.007.
    fn default() -> Self {
        RaslOptions {
            width: 100,
            height: 120,
            lambda_c: 1.0,
            outer_tolerance: 1e-2,
            inner_tolerance: 1e-7,
            rho: 1.5,
            max_outer: 50,
            max_inner: 1000,
        }
    }
}

/// One photo for RASL: its grey image (owned, or lent: RASL only reads it, and a caller that
/// keeps its photos need not copy them) and its points.
#[derive(Debug, Clone)]
pub struct RaslPhoto<'a> {
    /// The image.
    pub image: std::borrow::Cow<'a, GreyImage>,
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
    /// Wall time spent in the inner loops, seconds.
    pub inner_seconds: Real,
    /// Wall time of the whole alignment, seconds.
    pub seconds: Real,
    /// The options used.
    pub options: RaslOptions,
}

/// A column of the batch: an image (shared with its gradients) and its points.
struct Column {
    /// The part of the photo (or of its mirror image) that the warps reach ([`Column::new`]),
    /// and its gradients, each pixel's as in the whole image.
    image: GreyImage,
    gx: Vec<f32>,
    gy: Vec<f32>,
    /// Where the part's first pixel lies in the whole image (whole pixels).
    origin: Vector2<Real>,
    /// The whole image's width.
    full_width: usize,
    /// The 40 points, in the whole image's pixels.
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

fn from_matrix3(m: &Matrix3<Real>) -> Matrix2x3<Real> {
    m.fixed_view::<2, 3>(0, 0).into_owned()
}

/// Checks [`RaslOptions`]: window sides of 16 to 1024, positive weights and tolerances, a
/// penalty growth above 1, iteration caps of at least 1.
fn check_options(options: &RaslOptions) -> Result<(), AlignError> {
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
    if !(options.rho > 1.0 && options.rho.is_finite()) {
        return Err(bad_option(format!(
            "RASL option rho = {} must be above 1",
            options.rho
        )));
    }
    if options.max_outer == 0 || options.max_inner == 0 {
        return Err(bad_option("RASL iteration caps must be at least 1".into()));
    }
    Ok(())
}

/// Each usable photo's two columns (the photo, then its mirror image with its points mirrored
/// and relabelled), with the usable photos' names and the others' reasons.
fn columns_of(photos: &[RaslPhoto<'_>], options: &RaslOptions) -> (Vec<Column>, Vec<String>, Vec<Dropped>) {
    // Each photo's two columns are cut out side by side (the crops and their gradients are
    // copies of a few megabytes each), then listed in the photos' order.
    let window = (options.width, options.height);
    let made: Vec<Result<[Column; 2], Dropped>> = photos
        .par_iter()
        .map(|photo| {
            check(photo).map_err(|reason| Dropped {
                name: photo.points.name.clone(),
                reason,
            })?;
            let w = (photo.image.width() - 1) as Real;
            let mirrored_points: Vec<Point2<Real>> = structure::POINTS
                .iter()
                .map(|def| {
                    let p = photo.points.points[def.mirror];
                    Point2::new(w - p.x, p.y)
                })
                .collect();
            Ok([
                Column::new(&photo.image, false, photo.points.points.clone(), window),
                Column::new(&photo.image, true, mirrored_points, window),
            ])
        })
        .collect();
    let mut dropped = Vec::new();
    let mut kept = Vec::new();
    let mut columns = Vec::new();
    for (photo, made) in photos.iter().zip(made) {
        match made {
            Err(d) => dropped.push(d),
            Ok(pair) => {
                kept.push(photo.points.name.clone());
                columns.extend(pair);
            }
        }
    }
    (columns, kept, dropped)
}

/// The mean of the warps' matrices.
fn mean_warp(warps: &[Matrix2x3<Real>]) -> Matrix2x3<Real> {
    warps.iter().fold(Matrix2x3::zeros(), |s, w| s + w) / warps.len() as Real
}

/// Restores the mean warp after a step: `τᵢ ← τᵢ ∘ G` with `mean(τ ∘ G) = mean(τ⁰)` (left as
/// they are when the mean's linear part is singular).
fn restore_mean(warps: &mut [Matrix2x3<Real>], initial_mean: &Matrix2x3<Real>) {
    // Restore the mean warp: τᵢ ← τᵢ ∘ G with mean(τ ∘ G) = mean(τ⁰).
    let mean = mean_warp(warps);
    let (mean_linear, start_linear) = (
        mean.fixed_view::<2, 2>(0, 0).into_owned(),
        initial_mean.fixed_view::<2, 2>(0, 0).into_owned(),
    );
    if let Some(inverse) = mean_linear.try_inverse() {
        let g_linear = inverse * start_linear;
        let g_shift = inverse * (initial_mean.column(2) - mean.column(2));
        let g = crate::geometry::homogeneous(&crate::geometry::affine(&g_linear, &g_shift));
        for warp in warps.iter_mut() {
            *warp = from_matrix3(&(crate::geometry::homogeneous(warp) * g));
        }
    }
}

/// The frontal structure from the final warps: the mean of `τᵢ⁻¹(Sᵢ)` in window pixels (y
/// down), unified; each photo's and mirror's map to the frontal plane; the residual.
fn frontal_from_warps(columns: &[Column], warps: &[Matrix2x3<Real>]) -> Result<FrontalStructure, AlignError> {
    let bad_option = |what: String| AlignError::Frontal { problem: what };
    let n = columns.len();
    // The frontal structure: the mean of τᵢ⁻¹(Sᵢ), in window pixels (y down), then unified.
    let inverses: Vec<Matrix3<Real>> = warps
        .iter()
        .map(|w| {
            crate::geometry::homogeneous(w)
                .try_inverse()
                .unwrap_or_else(Matrix3::identity)
        })
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
            let w = (columns[k].full_width - 1) as Real;
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
    Ok(FrontalStructure {
        points: frontal_points,
        warps: photo_warps,
        mirror_warps,
        residual_rms,
        method: FrontalMethod::Rasl,
    })
}

/// Checks a photo for RASL.
fn check(photo: &RaslPhoto<'_>) -> Result<(), String> {
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

/// How far beyond the initial warp's reach a column's part of its photo extends, as a fraction
/// of that reach's larger side on every side: RASL's steps change a warp by a few percent, so
/// its samples stay inside; one that did not would read the part's border rather than the
/// photo's pixel beyond it.
const REACH_MARGIN: Real = 0.25;

impl Column {
    /// The column of `photo` (mirrored left to right when `mirror`) with its 40 `points` (in
    /// that image's pixels): only the part of the image that the RASL window (`window`,
    /// width and height) reaches under the initial warp, with [`REACH_MARGIN`], is kept, with
    /// its central-difference gradients taken in the whole image. Eight photos of a million
    /// pixels and their mirror images held whole with their gradients took about 150 MB, cut to
    /// their parts 95 MB (`lps-head`'s 8 photos); the samples, and so RASL's result, are the
    /// same while the warps stay within the margin (`structure.json` byte-identical on
    /// `lps-head`'s two photo sets).
    fn new(photo: &GreyImage, mirror: bool, points: Vec<Point2<Real>>, window: (usize, usize)) -> Self {
        let (w, h) = (photo.width(), photo.height());
        let tau = similarity(&canonical_anchors(window.0, window.1), &anchors(&points));
        let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)].map(|(a, b): (Real, Real)| {
            apply_affine(
                &tau,
                &Point2::new(a * (window.0 - 1) as Real, b * (window.1 - 1) as Real),
            )
        });
        let (lo, hi) = crate::geometry::bounding_box(&corners).expect("four corners");
        let margin = REACH_MARGIN * (hi.x - lo.x).max(hi.y - lo.y);
        let place = |v: Real, last: usize| v.clamp(0.0, last as Real) as usize;
        // The whole image when the warp is degenerate (RASL then fails on its own terms).
        let (x0, y0, x1, y1) = if margin.is_finite() && lo.x.is_finite() && lo.y.is_finite() {
            (
                place((lo.x - margin).floor(), w - 1),
                place((lo.y - margin).floor(), h - 1),
                place((hi.x + margin).ceil(), w - 1),
                place((hi.y + margin).ceil(), h - 1),
            )
        } else {
            (0, 0, w - 1, h - 1)
        };
        let data = photo.data();
        let at = |x: usize, y: usize| data[y * w + if mirror { w - 1 - x } else { x }];
        // The part with one more pixel on each side where the image has one: its central
        // differences inside that border are the whole image's (one-sided where the part
        // meets the image's own border, as there).
        let (px0, py0) = (x0.saturating_sub(1), y0.saturating_sub(1));
        let (px1, py1) = ((x1 + 1).min(w - 1), (y1 + 1).min(h - 1));
        let pw = px1 - px0 + 1;
        // Sized at once (collected from a flattening iterator, they grew by doubling, a copy
        // and fresh pages each time).
        let mut padded = Vec::with_capacity(pw * (py1 - py0 + 1));
        for y in py0..=py1 {
            padded.extend((px0..=px1).map(|x| at(x, y)));
        }
        let (pgx, pgy) = super::central_differences(&padded, pw, py1 - py0 + 1);
        let inner = |v: &[f32]| -> Vec<f32> {
            let mut part = Vec::with_capacity((x1 - x0 + 1) * (y1 - y0 + 1));
            for y in y0..=y1 {
                let row = (y - py0) * pw;
                part.extend_from_slice(&v[row + x0 - px0..=row + x1 - px0]);
            }
            part
        };
        let (values, gx, gy) = (inner(&padded), inner(&pgx), inner(&pgy));
        Column {
            image: GreyImage::new(x1 - x0 + 1, y1 - y0 + 1, values)
                .expect("a part of a valid image is valid"),
            gx,
            gy,
            origin: Vector2::new(x0 as Real, y0 as Real),
            full_width: w,
            points,
        }
    }

    /// The warped image (not normalised), vectorised column-major (pixel `(x, y)` at
    /// `x·height + y`), and, with `gradients`, the image gradients sampled at the same places:
    /// the Jacobian of the warped image in the affine parameters `[a11 a12 a13 a21 a22 a23]` is
    /// `[Iₓ·x, Iₓ·y, Iₓ, I_y·x, I_y·y, I_y]` per pixel.
    fn warp(
        &self,
        tau: &Matrix2x3<Real>,
        width: usize,
        height: usize,
        gradients: bool,
    ) -> (Vec<f32>, Vec<[f32; 2]>) {
        let d = width * height;
        let mut values = Vec::with_capacity(d);
        let mut sampled = Vec::with_capacity(if gradients { d } else { 0 });
        for x in 0..width {
            for y in 0..height {
                let (xf, yf) = (x as Real, y as Real);
                let u = tau[(0, 0)] * xf + tau[(0, 1)] * yf + tau[(0, 2)];
                let v = tau[(1, 0)] * xf + tau[(1, 1)] * yf + tau[(1, 2)];
                // Whole pixels subtracted from a place in the photo: exact.
                let (u, v) = (u - self.origin.x, v - self.origin.y);
                values.push(self.image.sample(self.image.data(), u, v));
                if gradients {
                    sampled.push([
                        self.image.sample(&self.gx, u, v),
                        self.image.sample(&self.gy, u, v),
                    ]);
                }
            }
        }
        (values, sampled)
    }
}

/// One column made ready for the inner loop: the normalised warped image `ỹ = y/‖y‖`, the
/// sampled gradients, and the factors of its Jacobian `J = (I − ỹỹᵀ)·G/‖y‖` (`G` the raw
/// Jacobian): `h = Gᵀỹ` and the upper-triangular `R` with `RᵀR = JᵀJ` (so `Q = J·R⁻¹` has
/// orthonormal columns, the thin QR factorisation, without storing `Q`).
struct Prepared {
    y: Vec<f32>,
    gradients: Vec<[f32; 2]>,
    norm: Real,
    h: nalgebra::Vector6<Real>,
    r: nalgebra::Matrix6<Real>,
}

/// The raw Jacobian row of window pixel `(x, y)` with gradient `g`.
fn jacobian_row(g: [f32; 2], x: Real, y: Real) -> nalgebra::Vector6<Real> {
    let (ix, iy) = (Real::from(g[0]), Real::from(g[1]));
    nalgebra::Vector6::new(ix * x, ix * y, ix, iy * x, iy * y, iy)
}

fn prepare(column: &Column, tau: &Matrix2x3<Real>, width: usize, height: usize) -> Prepared {
    let (values, gradients) = column.warp(tau, width, height, true);
    let norm = values
        .iter()
        .map(|v| Real::from(*v) * Real::from(*v))
        .sum::<Real>()
        .sqrt()
        .max(Real::MIN_POSITIVE);
    let y: Vec<f32> = values.iter().map(|v| (Real::from(*v) / norm) as f32).collect();
    let mut h = nalgebra::Vector6::zeros();
    let mut gram = nalgebra::Matrix6::zeros();
    for (j, (&g, &yj)) in gradients.iter().zip(&y).enumerate() {
        let row = jacobian_row(g, (j / height) as Real, (j % height) as Real);
        h += row * Real::from(yj);
        gram += row * row.transpose();
    }
    let mut jtj = (gram - h * h.transpose()) / (norm * norm);
    // A flat column has a singular Jacobian: a whisker of ridge keeps the factor defined (its
    // step is then ~0).
    let ridge = 1e-12 * jtj.trace().max(Real::MIN_POSITIVE);
    for k in 0..6 {
        jtj[(k, k)] += ridge;
    }
    let r = jtj
        .cholesky()
        .map(|c| c.l().transpose())
        .unwrap_or_else(nalgebra::Matrix6::identity);
    Prepared {
        y,
        gradients,
        norm,
        h,
        r,
    }
}

/// Pixels per parallel chunk of the inner loop's dual update, and per `f32` partial sum of the
/// warp steps (which decides their bits: see [`InnerContext::step_sums`]).
const CHUNK: usize = 512;

/// Pixels per parallel chunk of the singular-value thresholding's matrix products (large
/// enough for sgemm to run at speed, small enough to share among the threads).
const PRODUCT_CHUNK: usize = 2048;

// The inner loop's fused pass hands the warp steps' sums back per `CHUNK` pixels of each
// `PRODUCT_CHUNK` (see `inner_loop`): the one must divide the other.
const _: () = assert!(PRODUCT_CHUNK.is_multiple_of(CHUNK));

/// Singular-value thresholding of `t` at `threshold` through the Gram matrix (see the module
/// documentation): returns `U·max(Σ − threshold, 0)·Vᵀ`, the nuclear norm of the result, and
/// the largest singular value of `t`.
pub fn singular_value_threshold(t: &DMatrix<f32>, threshold: Real) -> (DMatrix<f32>, Real, Real) {
    let (d, n) = t.shape();
    let pixel_major = t.transpose();
    let mut out = vec![0.0f32; d * n];
    let (nuclear, largest) = svt_pixel_major(pixel_major.as_slice(), n, threshold, &mut out);
    (
        DMatrix::from_column_slice(n, d, &out).transpose(),
        nuclear,
        largest,
    )
}

/// [`singular_value_threshold`] on pixel-major storage (`t[j·n + k]` = pixel `j` of column
/// `k`, i.e. the `n × d` transpose in column-major order), writing into `out`; both products
/// run in parallel over chunks of pixels.
fn svt_pixel_major(t: &[f32], n: usize, threshold: Real, out: &mut [f32]) -> (Real, Real) {
    let grams: Vec<DMatrix<f32>> = t
        .par_chunks(PRODUCT_CHUNK * n)
        .map(|chunk| chunk_gram(chunk, n))
        .collect();
    let thresholded = Thresholded::new(grams, n, threshold);
    out.par_chunks_mut(PRODUCT_CHUNK * n)
        .zip(t.par_chunks(PRODUCT_CHUNK * n))
        .for_each(|(o, chunk)| thresholded.low_rank(chunk, n, o));
    (thresholded.nuclear, thresholded.largest)
}

/// One chunk's share `X·Xᵀ` of the Gram matrix (`chunk` pixel-major, `n` values a pixel), with
/// `Xᵀ` a strided view of the same memory (no copies: nalgebra hands both to
/// matrixmultiply's sgemm).
fn chunk_gram(chunk: &[f32], n: usize) -> DMatrix<f32> {
    let columns = chunk.len() / n;
    let x = nalgebra::DMatrixView::<f32>::from_slice(chunk, n, columns);
    let xt = nalgebra::DMatrixView::<f32, nalgebra::Dyn, nalgebra::Dyn>::from_slice_with_strides_generic(
        chunk,
        nalgebra::Dyn(columns),
        nalgebra::Dyn(n),
        nalgebra::Dyn(n),
        nalgebra::Dyn(1),
    );
    let mut g = DMatrix::<f32>::zeros(n, n);
    g.gemm(1.0, &x, &xt, 0.0);
    g
}

/// The singular-value thresholding of a matrix known by its Gram matrix: the kept singular
/// vectors and their shrunken weights, applied chunk by chunk by [`Thresholded::low_rank`].
struct Thresholded {
    /// The nuclear norm of the thresholded matrix.
    nuclear: Real,
    /// The largest singular value of the matrix.
    largest: Real,
    /// `(V_r, diag(w)·V_rᵀ)` with `wₖ = (σₖ − threshold)/σₖ`, or `None` when nothing is kept.
    factors: Option<(DMatrix<f32>, DMatrix<f32>)>,
}

impl Thresholded {
    /// From the chunks' shares of the Gram matrix, summed in chunk order (not by rayon's
    /// reduce, whose order follows the threads: the same input gives the same bits on any
    /// number of threads).
    fn new(grams: Vec<DMatrix<f32>>, n: usize, threshold: Real) -> Self {
        let gram32 = grams.into_iter().fold(DMatrix::<f32>::zeros(n, n), |a, b| a + b);
        let gram: DMatrix<Real> = gram32.map(Real::from);
        let eigen = gram.symmetric_eigen();
        // The kept singular vectors: A = V_r·diag(w)·V_rᵀ·T with wₖ = (σₖ − threshold)/σₖ, as
        // two thin products (rank r ≪ n in practice).
        let mut nuclear = 0.0;
        let mut largest: Real = 0.0;
        let mut kept_columns = Vec::new();
        let mut scaled_columns = Vec::new();
        for k in 0..n {
            let sigma = eigen.eigenvalues[k].max(0.0).sqrt();
            largest = largest.max(sigma);
            let kept = sigma - threshold;
            if kept > 0.0 {
                nuclear += kept;
                let v = eigen.eigenvectors.column(k).map(|x| x as f32);
                scaled_columns.push(&v * (kept / sigma) as f32);
                kept_columns.push(v);
            }
        }
        let factors = (!kept_columns.is_empty()).then(|| {
            (
                DMatrix::from_columns(&kept_columns),
                DMatrix::from_columns(&scaled_columns).transpose(),
            )
        });
        Thresholded {
            nuclear,
            largest,
            factors,
        }
    }

    /// The thresholded matrix over one chunk of pixels (`chunk` pixel-major, `n` values a
    /// pixel) into `out`.
    fn low_rank(&self, chunk: &[f32], n: usize, out: &mut [f32]) {
        let Some((basis, scaled_t)) = &self.factors else {
            out.fill(0.0);
            return;
        };
        let columns = chunk.len() / n;
        let view = nalgebra::DMatrixView::<f32>::from_slice(chunk, n, columns);
        let mut coefficients = DMatrix::<f32>::zeros(scaled_t.nrows(), columns);
        coefficients.gemm(1.0, scaled_t, &view, 0.0);
        let mut target = nalgebra::DMatrixViewMut::<f32>::from_slice(out, n, columns);
        target.gemm(1.0, basis, &coefficients, 0.0);
    }
}

/// `sign(x)·max(|x| − threshold, 0)`, without branches (the signs of `E`'s entries are
/// unpredictable, and mispredicted branches cost more than the arithmetic).
fn soft_threshold(x: f32, threshold: f32) -> f32 {
    (x - threshold).max(0.0) + (x + threshold).min(0.0)
}

/// Aligns the photos (and their mirror images) by RASL and returns the frontal structure
/// (see the module documentation). Photos whose points are unusable or lie outside their
/// image are left out and listed in [`RaslResult::dropped`].
///
/// # Errors
/// [`AlignError::NoPhotos`] for an empty batch, [`AlignError::Frontal`] when no photo is
/// usable (saying why each was dropped) or an option is out of range.
pub fn rasl_frontal(photos: &[RaslPhoto<'_>], options: &RaslOptions) -> Result<RaslResult, AlignError> {
    if photos.is_empty() {
        return Err(AlignError::NoPhotos);
    }
    check_options(options)?;
    let bad_option = |what: String| AlignError::Frontal { problem: what };
    let (columns, kept, dropped) = columns_of(photos, options);
    if columns.is_empty() {
        let reasons: Vec<String> = dropped
            .iter()
            .map(|d| format!("{}: {}", d.name, d.reason))
            .collect();
        return Err(bad_option(format!("no usable photo ({})", reasons.join("; "))));
    }

    let start = std::time::Instant::now();
    let mut inner_seconds = 0.0;
    let (width, height) = (options.width, options.height);
    let d = width * height;
    let n = columns.len();
    let lambda = options.lambda_c / (d as Real).sqrt();
    let window_anchors = canonical_anchors(width, height);
    let initial: Vec<Matrix2x3<Real>> = columns
        .iter()
        .map(|c| similarity(&window_anchors, &anchors(&c.points)))
        .collect();
    let initial_mean = mean_warp(&initial);
    let mut warps = initial.clone();

    let before = warped_matrix(&columns, &warps, width, height);
    let mut objective = Vec::new();
    let mut inner_total = 0;
    let mut low_rank = DMatrix::<f32>::zeros(d, n);
    let mut sparse = DMatrix::<f32>::zeros(d, n);
    let mut previous = Real::INFINITY;
    for _ in 0..options.max_outer {
        // Warp, normalise, differentiate, factor.
        let prepared: Vec<Prepared> = columns
            .par_iter()
            .zip(&warps)
            .map(|(column, tau)| prepare(column, tau, width, height))
            .collect();
        let mut data = DMatrix::<f32>::zeros(d, n);
        for (k, p) in prepared.iter().enumerate() {
            data.column_mut(k).copy_from_slice(&p.y);
        }
        let inner_start = std::time::Instant::now();
        let (a, e, steps, inner, value) = inner_loop(&data, &prepared, lambda, height, options);
        inner_seconds += inner_start.elapsed().as_secs_f64();
        inner_total += inner;
        low_rank = a;
        sparse = e;
        for (warp, step) in warps.iter_mut().zip(&steps) {
            for p in 0..6 {
                warp[(p / 3, p % 3)] += step[p];
            }
        }
        restore_mean(&mut warps, &initial_mean);
        objective.push(value);
        let improved = previous - value;
        previous = value;
        if improved.abs() < options.outer_tolerance * value.abs() {
            break;
        }
    }
    let after = warped_matrix(&columns, &warps, width, height);

    let frontal = frontal_from_warps(&columns, &warps)?;
    Ok(RaslResult {
        frontal,
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
        inner_seconds,
        seconds: start.elapsed().as_secs_f64(),
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

/// What every inner iteration of RASL reads: the data `D` (pixel-major, `dm[j·n + k]`), each
/// column's gradients (pixel-major too, `Iₓ` and `I_y` apart), its factors and its inverse
/// norm, each window pixel's `(x, y)`, and the number of columns.
struct InnerContext<'a> {
    dm: &'a [f32],
    gx: &'a [f32],
    gy: &'a [f32],
    prepared: &'a [Prepared],
    inverse_norm: &'a [f32],
    /// `(x, y)` of window pixel `j` (`j = x·height + y`), as `f32`.
    pixels: &'a [[f32; 2]],
    n: usize,
}

/// Columns handled side by side in the inner loop's per-pixel arithmetic: the same operations
/// on `LANES` columns at once, which the compiler keeps in vector registers (a batch has 14
/// columns for 7 photos: too few for it to vectorise a loop over them on its own). The
/// columns left over go two, then one, at a time through the same code, and every value is
/// computed by the same operations in the same order as one column at a time (the test
/// `the_lanes_give_the_column_by_column_values_bit_for_bit`).
const LANES: usize = 4;

/// `L` values side by side, added and multiplied lane by lane: each statement of the inner
/// loop's arithmetic is one operation on all of them, which the compiler turns into one vector
/// instruction (written lane by lane, it pairs the wrong operations). Each lane's value is
/// the one the same expression gives in `f32`, operation for operation.
#[derive(Clone, Copy)]
struct Lanes<const L: usize>([f32; L]);

impl<const L: usize> Lanes<L> {
    /// `values[at..at + L]`.
    #[inline(always)]
    fn load(values: &[f32], at: usize) -> Self {
        Lanes(values[at..at + L].try_into().expect("a slice of L values"))
    }

    /// `values[at..at + L] = self`.
    #[inline(always)]
    fn store(self, values: &mut [f32], at: usize) {
        values[at..at + L].copy_from_slice(&self.0);
    }

    /// Every lane `value`.
    #[inline(always)]
    fn splat(value: f32) -> Self {
        Lanes([value; L])
    }
}

macro_rules! lanes_operator {
    ($trait:ident, $method:ident, $op:tt) => {
        impl<const L: usize> std::ops::$trait for Lanes<L> {
            type Output = Self;
            #[inline(always)]
            fn $method(mut self, other: Self) -> Self {
                for (a, b) in self.0.iter_mut().zip(other.0) {
                    *a $op b;
                }
                self
            }
        }
    };
}
lanes_operator!(Add, add, +=);
lanes_operator!(Sub, sub, -=);
lanes_operator!(Mul, mul, *=);

impl InnerContext<'_> {
    /// One chunk's share of what the warp steps need (see [`InnerContext::warp_steps`]): for
    /// the pixels from `first` on (`a`, `e`, `y` this chunk's rows), per column the six sums of
    /// `Gᵀt` and the sum of `ỹᵀt`, `t = A + E − D − Y/μ`, summed in `f32` over every
    /// [`CHUNK`] pixels (in pixel order) and handed back in `f64`, one entry per `CHUNK` pixels
    /// in order.
    fn step_sums(
        &self,
        first: usize,
        (a, e, y): (&[f32], &[f32], &[f32]),
        inv_mu: f32,
    ) -> Vec<Vec<[Real; 7]>> {
        let n = self.n;
        let block = CHUNK * n;
        let chunks = a.chunks(block).zip(e.chunks(block)).zip(y.chunks(block));
        chunks
            .enumerate()
            .map(|(c, ((a, e), y))| {
                let first = first + c * CHUNK;
                let mut sums = vec![[0.0; 7]; n];
                let mut k = 0;
                while k < n {
                    k += match n - k {
                        LANES.. => self.column_sums::<LANES>(first, (a, e, y), k, inv_mu, &mut sums),
                        2..LANES => self.column_sums::<2>(first, (a, e, y), k, inv_mu, &mut sums),
                        _ => self.column_sums::<1>(first, (a, e, y), k, inv_mu, &mut sums),
                    };
                }
                sums
            })
            .collect()
    }

    /// [`InnerContext::step_sums`] of columns `k..k + L` over one run of pixels, into `sums`;
    /// returns `L`.
    #[inline(always)]
    fn column_sums<const L: usize>(
        &self,
        first: usize,
        (a, e, y): (&[f32], &[f32], &[f32]),
        k: usize,
        inv_mu: f32,
        sums: &mut [[Real; 7]],
    ) -> usize {
        let (dm, gx, gy, n) = (self.dm, self.gx, self.gy, self.n);
        let mut acc = [Lanes::<L>::splat(0.0); 7];
        let inv_mu = Lanes::splat(inv_mu);
        for r in 0..a.len() / n {
            let j = first + r;
            let [px, py] = self.pixels[j].map(Lanes::splat);
            let (o, x) = (r * n + k, j * n + k);
            let (a, e, y) = (Lanes::load(a, o), Lanes::load(e, o), Lanes::load(y, o));
            let (d, gx, gy) = (Lanes::load(dm, x), Lanes::load(gx, x), Lanes::load(gy, x));
            let target = a + e - d - y * inv_mu;
            let (tx, ty) = (gx * target, gy * target);
            acc[0] = acc[0] + tx * px;
            acc[1] = acc[1] + tx * py;
            acc[2] = acc[2] + tx;
            acc[3] = acc[3] + ty * px;
            acc[4] = acc[4] + ty * py;
            acc[5] = acc[5] + ty;
            acc[6] = acc[6] + d * target;
        }
        for (l, sum) in sums[k..k + L].iter_mut().enumerate() {
            *sum = std::array::from_fn(|i| Real::from(acc[i].0[l]));
        }
        L
    }

    /// The warp steps `Δτ` from the chunks' [`InnerContext::step_sums`], in pixel order.
    fn warp_steps(
        &self,
        partials: impl Iterator<Item = Vec<[Real; 7]>>,
        steps: &mut [nalgebra::Vector6<Real>],
    ) {
        // Δτ: δₖ = Qₖᵀtₖ for t = A + E − D − Y/μ, Δτₖ = Rₖ⁻¹δₖ. With Q = J·R⁻¹ and
        // Jᵀt = (Gᵀt − h·(ỹᵀt))/‖y‖: per column, the six sums of Gᵀt and ỹᵀt. The chunks'
        // sums are added in pixel order (the same bits on any number of threads).
        let sums = partials.fold(vec![[0.0; 7]; self.n], |mut s, p| {
            for (a, b) in s.iter_mut().zip(&p) {
                for i in 0..7 {
                    a[i] += b[i];
                }
            }
            s
        });
        for (k, (sum, column)) in sums.iter().zip(self.prepared).enumerate() {
            let gt = nalgebra::Vector6::from_column_slice(&sum[..6]);
            let jt = (gt - column.h * sum[6]) / column.norm;
            let delta = column
                .r
                .tr_solve_upper_triangular(&jt)
                .unwrap_or_else(nalgebra::Vector6::zeros);
            steps[k] = column
                .r
                .solve_upper_triangular(&delta)
                .unwrap_or_else(nalgebra::Vector6::zeros);
        }
    }

    /// `JΔτ` for the new `steps` into `dt`, the residual `Z = D + JΔτ − A − E`, and the dual
    /// update `Y += μZ`, in one pass; returns `‖Z‖²`, added up pixel by pixel, column by
    /// column, in `f64` (the order that decides when the inner loop stops).
    ///
    /// Pixel by pixel, each column block reads its seven coefficients again. Measured and
    /// dropped: each chunk taken column block by column block, as [`InnerContext::step_sums`]
    /// does, reading the coefficients once a block (the same bits; 4.5% fewer instructions
    /// for 7 synthetic photos' alignment, but 0.99–1.05 of the time on one thread, four rounds
    /// by turns: the chunk's arrays are then swept once a block instead of once).
    fn dual_step(
        &self,
        steps: &[nalgebra::Vector6<Real>],
        (a, e): (&[f32], &[f32]),
        (dt, y): (&mut [f32], &mut [f32]),
        mu: Real,
    ) -> Real {
        let n = self.n;
        let block = CHUNK * n;
        // Per column, JΔτ at pixel j is (Gⱼ·Δτ − ỹⱼ·(h·Δτ))/‖y‖: the seven coefficients
        // (Δτ and h·Δτ), each a row of n.
        let mut coefficients = vec![0.0f32; 7 * n];
        for (k, (s, p)) in steps.iter().zip(self.prepared).enumerate() {
            let hs = p.h.dot(s);
            for (i, v) in [s[0], s[1], s[2], s[3], s[4], s[5], hs].into_iter().enumerate() {
                coefficients[i * n + k] = v as f32;
            }
        }
        let coefficients = rows::<7>(&coefficients, n);
        // JΔτ, the residual Z = D + JΔτ − A − E, and Y += μZ, in one pass.
        let mu32 = mu as f32;
        dt.par_chunks_mut(block)
            .zip(y.par_chunks_mut(block))
            .enumerate()
            .map(|(c, (dt_chunk, y_chunk))| {
                let mut sum = 0.0f64;
                let mut z = vec![0.0f32; n];
                let rows = dt_chunk.chunks_exact_mut(n).zip(y_chunk.chunks_exact_mut(n));
                for (r, (dt_row, y_row)) in rows.enumerate() {
                    let j = c * CHUNK + r;
                    let mut k = 0;
                    while k < n {
                        let row = (j, &mut *dt_row, &mut *y_row, &mut z[..]);
                        k += match n - k {
                            LANES.. => self.dual_columns::<LANES>(&coefficients, (a, e), row, k, mu32),
                            2..LANES => self.dual_columns::<2>(&coefficients, (a, e), row, k, mu32),
                            _ => self.dual_columns::<1>(&coefficients, (a, e), row, k, mu32),
                        };
                    }
                    for &z in &z {
                        sum += Real::from(z) * Real::from(z);
                    }
                }
                sum
            })
            .collect::<Vec<Real>>()
            .iter()
            .sum()
    }

    /// [`InnerContext::dual_step`] at pixel `j` for columns `k..k + L`: `JΔτ` into `dt_row`,
    /// `Y += μZ` into `y_row`, and `Z` into `z`; returns `L`.
    #[inline(always)]
    fn dual_columns<const L: usize>(
        &self,
        coefficients: &[&[f32]; 7],
        (a, e): (&[f32], &[f32]),
        (j, dt_row, y_row, z): (usize, &mut [f32], &mut [f32], &mut [f32]),
        k: usize,
        mu: f32,
    ) -> usize {
        let [px, py] = self.pixels[j].map(Lanes::<L>::splat);
        let x = j * self.n + k;
        let (d, gx, gy) = (
            Lanes::load(self.dm, x),
            Lanes::load(self.gx, x),
            Lanes::load(self.gy, x),
        );
        let (a, e) = (Lanes::load(a, x), Lanes::load(e, x));
        let c: [Lanes<L>; 7] = std::array::from_fn(|i| Lanes::load(coefficients[i], k));
        let inverse_norm = Lanes::load(self.inverse_norm, k);
        let g_dot = gx * (c[0] * px + c[1] * py + c[2]) + gy * (c[3] * px + c[4] * py + c[5]);
        let step = (g_dot - d * c[6]) * inverse_norm;
        step.store(dt_row, k);
        let residual = d + step - a - e;
        residual.store(z, k);
        (Lanes::load(y_row, k) + Lanes::splat(mu) * residual).store(y_row, k);
        L
    }
}

/// `(x, y)` of each of a window's `d` pixels as [`InnerContext::pixels`] holds them (pixel
/// `j = x·height + y`).
fn window_pixels(d: usize, height: usize) -> Vec<[f32; 2]> {
    (0..d)
        .map(|j| [(j / height) as f32, (j % height) as f32])
        .collect()
}

/// `values` (`N` rows of `n`, one after another) as its `N` rows.
fn rows<const N: usize>(values: &[f32], n: usize) -> [&[f32]; N] {
    std::array::from_fn(|i| &values[i * n..(i + 1) * n])
}

/// The inner augmented-Lagrange loop: returns `A`, `E` (`d × n`), the warp steps `Δτᵢ`, the
/// iterations run and the objective `‖A‖_* + λ‖E‖₁`.
///
/// Everything is stored pixel-major (`[j·n + k]`, see [`svt_pixel_major`]). An iteration makes
/// three parallel passes over the pixels, chunk by chunk (each ends where the next needs the
/// whole of it): `T` and its Gram matrix; `A` (the thresholding's products), `E` and the sums
/// of the warp steps; then `JΔτ` and the dual update ([`InnerContext::dual_step`]); the
/// per-pixel arithmetic of the last two runs [`LANES`] columns at a time. Every value is the
/// one that a pass each, column by column, gave, in the same order, so the result is the same
/// bit for bit (`structure.json` and RASL's figures in `report.json` unchanged on
/// `lps-head/photos-8`). Measured on 7 synthetic photos (14 columns, 125 inner iterations, ten
/// alignments a run, the two builds by turns): the inner loops' time 0.74–0.88 of the former
/// code's on one thread (four rounds), 0.70–1.02 on two (five rounds; median 1.33 against
/// 1.75 s). The passes fused without the lanes were no faster: the per-pixel loops over 14
/// columns ran one column at a time (the compiler does not vectorise so short a loop), and
/// they were half of the time.
fn inner_loop(
    data: &DMatrix<f32>,
    prepared: &[Prepared],
    lambda: Real,
    height: usize,
    options: &RaslOptions,
) -> (
    DMatrix<f32>,
    DMatrix<f32>,
    Vec<nalgebra::Vector6<Real>>,
    usize,
    Real,
) {
    let (d, n) = data.shape();
    let dm = data.transpose();
    let dm = dm.as_slice();
    // Gradients, pixel-major: gx[j·n + k], gy[j·n + k] = Iₓ, I_y of column k at pixel j.
    let mut gx = vec![0.0f32; d * n];
    let mut gy = vec![0.0f32; d * n];
    gx.par_chunks_mut(n)
        .zip(gy.par_chunks_mut(n))
        .enumerate()
        .for_each(|(j, (x_row, y_row))| {
            for (k, (x, y)) in x_row.iter_mut().zip(y_row).enumerate() {
                [*x, *y] = prepared[k].gradients[j];
            }
        });
    let inverse_norm: Vec<f32> = prepared.iter().map(|p| (1.0 / p.norm) as f32).collect();
    let pixels = window_pixels(d, height);
    let context = InnerContext {
        dm,
        gx: &gx,
        gy: &gy,
        prepared,
        inverse_norm: &inverse_norm,
        pixels: &pixels,
        n,
    };
    // ‖D‖₂ from D's Gram matrix alone (nothing of D is kept at an infinite threshold).
    let grams: Vec<DMatrix<f32>> = dm
        .par_chunks(PRODUCT_CHUNK * n)
        .map(|chunk| chunk_gram(chunk, n))
        .collect();
    let two_norm = Thresholded::new(grams, n, Real::INFINITY).largest;
    let inf_norm = dm.iter().fold(0.0f32, |m, v| m.max(v.abs())) as Real / lambda;
    let dual = two_norm.max(inf_norm);
    let mut y: Vec<f32> = dm.iter().map(|v| v / dual as f32).collect();
    let mut mu = 1.25 / two_norm;
    let rho = options.rho;
    let data_norm = dm
        .iter()
        .map(|v| Real::from(*v) * Real::from(*v))
        .sum::<Real>()
        .sqrt();
    let mut e = vec![0.0f32; d * n];
    let mut a = vec![0.0f32; d * n];
    let mut dt = vec![0.0f32; d * n];
    let mut t = vec![0.0f32; d * n];
    let mut steps = vec![nalgebra::Vector6::<Real>::zeros(); n];
    let mut nuclear = 0.0;
    let mut iterations = 0;
    let block = PRODUCT_CHUNK * n;
    for _ in 0..options.max_inner {
        iterations += 1;
        let inv_mu = (1.0 / mu) as f32;
        // T = D + JΔτ − E + Y/μ, and its Gram matrix.
        let grams: Vec<DMatrix<f32>> = t
            .par_chunks_mut(block)
            .enumerate()
            .map(|(c, out)| {
                let o = c * block;
                let end = o + out.len();
                let inputs = dm[o..end].iter().zip(&dt[o..end]).zip(&e[o..end]).zip(&y[o..end]);
                for (v, (((d, dt), e), y)) in out.iter_mut().zip(inputs) {
                    *v = d + dt - e + y * inv_mu;
                }
                chunk_gram(out, n)
            })
            .collect();
        // A: singular-value thresholding of T; E: soft thresholding of D + JΔτ − A + Y/μ;
        // and the sums of the warp steps, which read both.
        let thresholded = Thresholded::new(grams, n, 1.0 / mu);
        nuclear = thresholded.nuclear;
        let shrink = (lambda / mu) as f32;
        let partials: Vec<Vec<Vec<[Real; 7]>>> = a
            .par_chunks_mut(block)
            .zip(e.par_chunks_mut(block))
            .enumerate()
            .map(|(c, (a, e))| {
                let o = c * block;
                let end = o + a.len();
                thresholded.low_rank(&t[o..end], n, a);
                let inputs = dm[o..end].iter().zip(&dt[o..end]).zip(&*a).zip(&y[o..end]);
                for (v, (((d, dt), a), y)) in e.iter_mut().zip(inputs) {
                    *v = soft_threshold(d + dt - a + y * inv_mu, shrink);
                }
                context.step_sums(c * PRODUCT_CHUNK, (a, e, &y[o..end]), inv_mu)
            })
            .collect();
        context.warp_steps(partials.into_iter().flatten(), &mut steps);
        let residual_squared = context.dual_step(&steps, (&a, &e), (&mut dt, &mut y), mu);
        mu *= rho;
        if residual_squared.sqrt() / data_norm < options.inner_tolerance {
            break;
        }
    }
    let l1: Real = e.iter().map(|v| Real::from(v.abs())).sum();
    let a = DMatrix::from_column_slice(n, d, &a).transpose();
    let e = DMatrix::from_column_slice(n, d, &e).transpose();
    (a, e, steps, iterations, nuclear + lambda * l1)
}

/// A column (`d = width × height` values, column-major) as an 8-bit image, mapped by `scale`.
fn column_image(values: &[f32], width: usize, height: usize, scale: impl Fn(f32) -> f32) -> image::GrayImage {
    image::GrayImage::from_fn(width as u32, height as u32, |x, y| {
        let v = scale(values[x as usize * height + y as usize]);
        image::Luma([(255.0 * v.clamp(0.0, 1.0)).round() as u8])
    })
}

/// The columns of `m` side by side in a grid of `per_row` columns, each mapped by `scale`.
fn mosaic(
    m: &DMatrix<f32>,
    width: usize,
    height: usize,
    scale: impl Fn(usize, f32) -> f32,
) -> image::GrayImage {
    let n = m.ncols();
    let per_row = (n as Real).sqrt().ceil().max(1.0) as usize;
    let rows = n.div_ceil(per_row);
    let mut out = image::GrayImage::new((per_row * width) as u32, (rows * height) as u32);
    for k in 0..n {
        let tile = column_image(m.column(k).as_slice(), width, height, |v| scale(k, v));
        let (x0, y0) = ((k % per_row) * width, (k / per_row) * height);
        for (x, y, p) in tile.enumerate_pixels() {
            out.put_pixel(x0 as u32 + x, y0 as u32 + y, *p);
        }
    }
    out
}

impl RaslResult {
    /// Pictures of the alignment for people to look at, as `(file name, PNG bytes)`: the warped
    /// photos and mirrors before and after (`before.png`, `aligned.png`, a grid in batch order:
    /// photo, mirror, photo, …), the low-rank part (`low-rank.png`, each column stretched to
    /// its range), the sparse part (`sparse.png`, `|E|` over its largest value) and the mean
    /// window before and after alignment (`mean-before.png`, `mean-after.png`: a sharp mean is
    /// a good alignment).
    ///
    /// # Errors
    /// The PNG encoder's message.
    pub fn images(&self) -> Result<Vec<(String, Vec<u8>)>, crate::io::EncodeError> {
        let (w, h) = (self.options.width, self.options.height);
        let identity = |_: usize, v: f32| v;
        let stretch = |m: &DMatrix<f32>| {
            let ranges: Vec<(f32, f32)> = m
                .column_iter()
                .map(|c| {
                    c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                        (lo.min(v), hi.max(v))
                    })
                })
                .collect();
            move |k: usize, v: f32| {
                let (lo, hi) = ranges[k];
                if hi > lo { (v - lo) / (hi - lo) } else { 0.0 }
            }
        };
        let largest = self
            .sparse
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()))
            .max(f32::MIN_POSITIVE);
        let mean = |m: &DMatrix<f32>| {
            let values: Vec<f32> = m.row_iter().map(|r| r.sum() / m.ncols() as f32).collect();
            column_image(&values, w, h, |v| v)
        };
        Ok(vec![
            (
                "before.png".to_owned(),
                crate::io::encode_png(&mosaic(&self.before, w, h, identity))?,
            ),
            (
                "aligned.png".to_owned(),
                crate::io::encode_png(&mosaic(&self.after, w, h, identity))?,
            ),
            (
                "low-rank.png".to_owned(),
                crate::io::encode_png(&mosaic(&self.low_rank, w, h, stretch(&self.low_rank)))?,
            ),
            (
                "sparse.png".to_owned(),
                crate::io::encode_png(&mosaic(&self.sparse, w, h, |_, v| v.abs() / largest))?,
            ),
            (
                "mean-before.png".to_owned(),
                crate::io::encode_png(&mean(&self.before))?,
            ),
            (
                "mean-after.png".to_owned(),
                crate::io::encode_png(&mean(&self.after))?,
            ),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Lcg;

    fn values(rng: &mut Lcg, count: usize) -> Vec<f32> {
        (0..count).map(|_| rng.uniform(-1.0, 1.0) as f32).collect()
    }

    /// The inner loop's per-pixel kernels, [`LANES`] columns at a time, against the same
    /// formulas one column at a time (as the code before them computed them), to the bit: for
    /// column counts that take every path (4, 2 and 1 at a time) and a window that is not a
    /// whole number of chunks.
    #[test]
    fn the_lanes_give_the_column_by_column_values_bit_for_bit() {
        let (width, height) = (7, 150);
        let d = width * height;
        for n in [1, 2, 3, 4, 5, 7, 14] {
            let mut rng = Lcg(n as u64);
            let [dm, gx, gy, a, e, y] = std::array::from_fn(|_| values(&mut rng, d * n));
            let prepared: Vec<Prepared> = (0..n)
                .map(|_| Prepared {
                    y: Vec::new(),
                    gradients: Vec::new(),
                    norm: 1.0,
                    h: nalgebra::Vector6::from_fn(|_, _| rng.uniform(-1.0, 1.0)),
                    r: nalgebra::Matrix6::identity(),
                })
                .collect();
            let inverse_norm = values(&mut rng, n);
            let pixels = window_pixels(d, height);
            let context = InnerContext {
                dm: &dm,
                gx: &gx,
                gy: &gy,
                prepared: &prepared,
                inverse_norm: &inverse_norm,
                pixels: &pixels,
                n,
            };
            let inv_mu = 0.37f32;
            let place = |j: usize| ((j / height) as f32, (j % height) as f32);

            let sums = context.step_sums(0, (&a, &e, &y), inv_mu);
            assert_eq!(sums.len(), d.div_ceil(CHUNK));
            for (c, chunk) in sums.iter().enumerate() {
                for (k, got) in chunk.iter().enumerate() {
                    let mut acc = [0.0f32; 7];
                    for j in c * CHUNK..((c + 1) * CHUNK).min(d) {
                        let x = j * n + k;
                        let (px, py) = place(j);
                        let target = a[x] + e[x] - dm[x] - y[x] * inv_mu;
                        let (tx, ty) = (gx[x] * target, gy[x] * target);
                        acc[0] += tx * px;
                        acc[1] += tx * py;
                        acc[2] += tx;
                        acc[3] += ty * px;
                        acc[4] += ty * py;
                        acc[5] += ty;
                        acc[6] += dm[x] * target;
                    }
                    assert_eq!(
                        got.map(Real::to_bits),
                        acc.map(|v| Real::from(v).to_bits()),
                        "n {n}, chunk {c}, column {k}"
                    );
                }
            }

            let steps: Vec<nalgebra::Vector6<Real>> = (0..n)
                .map(|_| nalgebra::Vector6::from_fn(|_, _| rng.uniform(-1.0, 1.0)))
                .collect();
            let mu = 1.7;
            let (mut dt, mut y_new) = (vec![0.0f32; d * n], y.clone());
            let total = context.dual_step(&steps, (&a, &e), (&mut dt, &mut y_new), mu);
            let mut expected_y = y.clone();
            let mut chunk_sums = Vec::new();
            for c in 0..d.div_ceil(CHUNK) {
                let mut sum = 0.0f64;
                for j in c * CHUNK..((c + 1) * CHUNK).min(d) {
                    let (px, py) = place(j);
                    for k in 0..n {
                        let x = j * n + k;
                        let s = steps[k].map(|v| v as f32);
                        let hs = prepared[k].h.dot(&steps[k]) as f32;
                        let g_dot =
                            gx[x] * (s[0] * px + s[1] * py + s[2]) + gy[x] * (s[3] * px + s[4] * py + s[5]);
                        let step = (g_dot - dm[x] * hs) * inverse_norm[k];
                        assert_eq!(dt[x].to_bits(), step.to_bits(), "n {n}, pixel {j}, column {k}");
                        let z = dm[x] + step - a[x] - e[x];
                        sum += Real::from(z) * Real::from(z);
                        expected_y[x] += mu as f32 * z;
                    }
                }
                chunk_sums.push(sum);
            }
            assert_eq!(
                y_new.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                expected_y.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "n {n}"
            );
            assert_eq!(
                total.to_bits(),
                chunk_sums.iter().sum::<Real>().to_bits(),
                "n {n}"
            );
        }
    }
}
