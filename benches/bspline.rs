//! Speed of the B-spline kernel on one core (a one-thread rayon pool), cubic surfaces.
//!
//! Targets (issue 2): scattered evaluation ≥ 20 M points/s and a dense 1000 × 1000 grid
//! ≥ 150 M points/s on a 32 × 32 grid; fitting 10⁵ samples to 32 × 32 in ≤ 30 ms and 10⁶
//! samples to 64 × 64 in ≤ 300 ms. `dense grid/pointwise` is the baseline the separable grid
//! evaluation is measured against in the same run.
//!
//! Knot insertion, refinement, elevation and Bézier extraction of a 64 × 64 grid are timed
//! too (issue 24), and so is `scattered/eval_many_into` against its target there of
//! ≥ 80 M points/s (SIMD lanes); `scattered/eval loop` (`eval` one point at a time) is the
//! scalar path it is measured against in the same run.
//!
//! Run: `cargo bench --bench bspline`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Point3;
use splineface::bspline::{BSplineSurface, KnotVector, SurfaceFit};
use std::hint::black_box;
use std::time::Duration;

use splineface::random::Lcg;

fn cubic_surface(n: usize) -> BSplineSurface {
    let k = KnotVector::clamped_uniform(3, n, 0.0, 1.0).unwrap();
    let mut rng = Lcg(1);
    let grid = (0..n * n)
        .map(|i| Point3::new((i / n) as f64, (i % n) as f64, rng.next()))
        .collect();
    BSplineSurface::new(k.clone(), k, n, n, grid).unwrap()
}

fn one_thread() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap()
}

fn evaluation(c: &mut Criterion) {
    let pool = one_thread();
    let s = cubic_surface(32);
    let mut rng = Lcg(2);
    let params: Vec<[f64; 2]> = (0..1_000_000).map(|_| [rng.next(), rng.next()]).collect();

    let mut g = c.benchmark_group("scattered");
    g.throughput(Throughput::Elements(params.len() as u64));
    g.sample_size(20);
    g.bench_function("eval_many 32x32 1M", |b| {
        b.iter(|| pool.install(|| black_box(s.eval_many(black_box(&params)).unwrap())))
    });
    g.bench_function("eval_many_into 32x32 1M", |b| {
        let mut out = vec![Point3::origin(); params.len()];
        b.iter(|| pool.install(|| s.eval_many_into(black_box(&params), &mut out).unwrap()))
    });
    g.bench_function("eval loop 32x32 1M", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for &[u, v] in &params {
                acc += s.eval(u, v).unwrap().z;
            }
            black_box(acc)
        })
    });
    g.finish();

    let grid: Vec<f64> = (0..1000).map(|i| i as f64 / 999.0).collect();
    let mut g = c.benchmark_group("dense grid");
    g.throughput(Throughput::Elements(1_000_000));
    g.sample_size(20);
    g.bench_function("eval_grid 32x32 1000x1000", |b| {
        let mut out = vec![Point3::origin(); 1_000_000];
        b.iter(|| {
            pool.install(|| {
                s.eval_grid_into(black_box(&grid), black_box(&grid), &mut out)
                    .unwrap()
            })
        })
    });
    g.bench_function("pointwise 32x32 1000x1000", |b| {
        let mut out = vec![Point3::origin(); 1_000_000];
        b.iter(|| {
            for (i, &u) in grid.iter().enumerate() {
                for (j, &v) in grid.iter().enumerate() {
                    out[i * 1000 + j] = s.eval(u, v).unwrap();
                }
            }
            black_box(&out);
        })
    });
    g.finish();
}

fn fitting(c: &mut Criterion) {
    let pool = one_thread();
    let mut g = c.benchmark_group("fit");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(10));
    for (samples, n) in [(100_000usize, 32usize), (1_000_000, 64)] {
        let truth = cubic_surface(n);
        let mut rng = Lcg(3);
        let params: Vec<[f64; 2]> = (0..samples).map(|_| [rng.next(), rng.next()]).collect();
        let points = truth.eval_many(&params).unwrap();
        let k = KnotVector::clamped_uniform(3, n, 0.0, 1.0).unwrap();
        g.throughput(Throughput::Elements(samples as u64));
        g.bench_with_input(BenchmarkId::new(format!("{n}x{n}"), samples), &samples, |b, _| {
            b.iter(|| {
                pool.install(|| {
                    black_box(
                        SurfaceFit::new(k.clone(), k.clone())
                            .fit(&params, &points)
                            .unwrap(),
                    )
                })
            })
        });
        g.bench_with_input(
            BenchmarkId::new(format!("{n}x{n} smoothed"), samples),
            &samples,
            |b, _| {
                b.iter(|| {
                    pool.install(|| {
                        black_box(
                            SurfaceFit::new(k.clone(), k.clone())
                                .smoothness(1e-8)
                                .fit(&params, &points)
                                .unwrap(),
                        )
                    })
                })
            },
        );
    }
    g.finish();
}

/// Knot insertion, refinement, degree elevation and Bézier extraction of a 64 × 64 bicubic grid
/// (issue 24: "in microseconds").
fn refinement(c: &mut Criterion) {
    use splineface::bspline::Direction;
    let s = cubic_surface(64);
    let mut g = c.benchmark_group("refinement 64x64");
    g.sample_size(30);
    g.bench_function("insert one knot in u", |b| {
        b.iter(|| black_box(s.insert_knot(Direction::U, black_box(0.4321), 1).unwrap()))
    });
    g.bench_function("insert a knot 3 times in u", |b| {
        b.iter(|| black_box(s.insert_knot(Direction::U, black_box(0.4321), 3).unwrap()))
    });
    let values: Vec<f64> = (1..64).map(|k| (k as f64 - 0.5) / 63.0).collect();
    g.bench_function("refine by 63 knots in v", |b| {
        b.iter(|| black_box(s.refine_knots(Direction::V, black_box(&values)).unwrap()))
    });
    g.bench_function("elevate degree by 1 in u", |b| {
        b.iter(|| black_box(s.elevate_degree(Direction::U, 1).unwrap()))
    });
    g.bench_function("split in u", |b| {
        b.iter(|| black_box(s.split(Direction::U, black_box(0.4321)).unwrap()))
    });
    g.bench_function("bezier patches (3721)", |b| {
        b.iter(|| black_box(s.bezier_patches().unwrap()))
    });
    g.finish();
}

/// Point inversion on a 32 × 32 bicubic grid (issue 24's target: ≥ 2 M queries/s on one core
/// for points 0.1% of the surface's size from it).
fn inversion(c: &mut Criterion) {
    use splineface::bspline::ClosestPoints;
    let pool = one_thread();
    let s = cubic_surface(32);
    let inverter = ClosestPoints::new(&s);
    let mut rng = Lcg(4);
    // The grid spans 31 × 31 units: 0.1% of its size is about 0.044.
    let queries: Vec<Point3<f64>> = (0..100_000)
        .map(|_| {
            let (u, v) = (rng.next(), rng.next());
            let n = s.normal(u, v).unwrap().unwrap().into_inner();
            s.eval(u, v).unwrap() + n * (0.088 * rng.next() - 0.044)
        })
        .collect();
    let mut g = c.benchmark_group("inversion");
    g.throughput(Throughput::Elements(queries.len() as u64));
    g.sample_size(20);
    g.bench_function("closest 32x32 100k at 0.1%", |b| {
        b.iter(|| pool.install(|| black_box(inverter.closest_many(black_box(&queries)).unwrap())))
    });
    g.bench_function("build 32x32", |b| {
        b.iter(|| black_box(ClosestPoints::new(black_box(&s))))
    });
    g.finish();
}

criterion_group!(benches, evaluation, fitting, refinement, inversion);
criterion_main!(benches);
