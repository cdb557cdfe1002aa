//! RASL: a batch made from one face image warped by known affine maps, some copies occluded.

use nalgebra::{DMatrix, Matrix2x3, Point2};
use splineface::Real;
use splineface::align::{
    AlignError, FrontalMethod, GreyImage, PhotoPoints, PhotoProblem, RaslOptions, RaslPhoto, apply_affine,
    rasl_frontal, singular_value_threshold,
};
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::geometry::{affine, homogeneous};
use splineface::reference::ReferenceFace;
use splineface::render::{View, synthetic_photo};
use std::borrow::Cow;

use crate::common::Lcg;

/// A synthetic face photo of the reference face from the front, and its 40 points.
pub fn face_photo(width: usize, height: usize) -> (GreyImage, Vec<Point2<Real>>) {
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let mesh = face.mesh(&MeshOptions { spacing: 1.0 }).unwrap().mesh;
    let photo = synthetic_photo(&mesh, r.structure(), &View::front(), width, height, 0.12).unwrap();
    (photo.image, photo.points)
}

/// The copy `C(q) = B(M q)` of `base`, with `M` the given affine map of pixels.
fn warped_copy(base: &GreyImage, m: &Matrix2x3<Real>) -> GreyImage {
    let (w, h) = (base.width(), base.height());
    let mut data = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let p = apply_affine(m, &Point2::new(x as Real, y as Real));
            data.push(base.sample(base.data(), p.x, p.y));
        }
    }
    GreyImage::new(w, h, data).unwrap()
}

struct Batch {
    photos: Vec<RaslPhoto<'static>>,
    /// `M_i`: copy pixels → base pixels.
    maps: Vec<Matrix2x3<Real>>,
    base_points: Vec<Point2<Real>>,
    /// Occluded copies and their block (x0, y0, size) in copy pixels.
    blocks: Vec<(usize, usize, usize, usize)>,
}

fn batch(copies: usize, noise: Real, seed: u64) -> Batch {
    let (base, base_points) = face_photo(200, 240);
    let mut rng = Lcg(seed);
    let centre = Point2::new(100.0, 120.0);
    let mut photos = Vec::new();
    let mut maps = Vec::new();
    let mut blocks = Vec::new();
    for i in 0..copies {
        let angle: Real = rng.uniform(-8.0, 8.0).to_radians();
        let (sx, sy, shear) = (
            rng.uniform(0.92, 1.08),
            rng.uniform(0.92, 1.08),
            rng.uniform(-0.06, 0.06),
        );
        let linear = nalgebra::Matrix2::new(angle.cos(), -angle.sin(), angle.sin(), angle.cos())
            * nalgebra::Matrix2::new(sx, shear, 0.0, sy);
        let shift = nalgebra::Vector2::new(rng.uniform(-6.0, 6.0), rng.uniform(-6.0, 6.0));
        let t = centre.coords + shift - linear * centre.coords;
        let m = affine(&linear, &t);
        let mut image = warped_copy(&base, &m);
        let inverse = homogeneous(&m).try_inverse().unwrap();
        let inverse = inverse.fixed_view::<2, 3>(0, 0).into_owned();
        let points: Vec<Point2<Real>> = base_points
            .iter()
            .map(|p| {
                apply_affine(&inverse, p)
                    + nalgebra::Vector2::new(noise * rng.gaussian(), noise * rng.gaussian())
            })
            .collect();
        if i % 4 == 1 {
            // An occluding block over the right cheek.
            let (x0, y0, size) = ((points[2].x + 10.0) as usize, (points[2].y - 25.0) as usize, 24);
            let mut data = image.data().to_vec();
            for y in y0..y0 + size {
                for x in x0..x0 + size {
                    data[y * 200 + x] = if (x / 4 + y / 4) % 2 == 0 { 1.0 } else { 0.0 };
                }
            }
            image = GreyImage::new(200, 240, data).unwrap();
            blocks.push((i, x0, y0, size));
        }
        photos.push(RaslPhoto {
            image: Cow::Owned(image),
            points: PhotoPoints::new(format!("copy{i}"), points).unwrap(),
        });
        maps.push(m);
    }
    Batch {
        photos,
        maps,
        base_points,
        blocks,
    }
}

#[test]
fn rasl_undoes_known_warps_and_puts_occlusions_in_the_sparse_part() {
    let b = batch(10, 1.5, 5);
    let options = RaslOptions::default();
    let result = rasl_frontal(&b.photos, &options).unwrap();
    assert!(result.dropped.is_empty(), "{:?}", result.dropped);
    assert_eq!(result.frontal.method, FrontalMethod::Rasl);
    result.frontal.validate().unwrap();
    // Where the true landmarks land in the window: (Mᵢ τᵢ)⁻¹(b_k), the same for all copies when
    // aligned. Inner-face points (brows to mouth) inside the window.
    let spread = |warps: &[Matrix2x3<Real>]| -> Real {
        let mut worst: Real = 0.0;
        for k in 9..40 {
            let seen: Vec<Point2<Real>> = (0..b.photos.len())
                .map(|i| {
                    let composed = homogeneous(&b.maps[i]) * homogeneous(&warps[2 * i]);
                    let inverse = composed
                        .try_inverse()
                        .unwrap()
                        .fixed_view::<2, 3>(0, 0)
                        .into_owned();
                    apply_affine(&inverse, &b.base_points[k])
                })
                .collect();
            for i in 0..seen.len() {
                for j in 0..i {
                    worst = worst.max((seen[i] - seen[j]).norm());
                }
            }
        }
        worst
    };
    let before = spread(&result.initial_warps);
    let after = spread(&result.warps);
    println!(
        "worst landmark disagreement: {before:.2} px before, {after:.3} px after; outer {} inner {}",
        result.objective.len(),
        result.inner_iterations
    );
    assert!(before > 2.0, "the test needs misaligned starts: {before}");
    assert!(after < 0.5, "after RASL: {after} px");
    // The occluders land in the sparse part: mean |E| inside each block, mapped into the
    // window, is far above the mean elsewhere.
    let (w, h) = (options.width, options.height);
    for &(i, x0, y0, size) in &b.blocks {
        let column = 2 * i;
        let tau = result.warps[column];
        let (mut inside, mut n_in, mut outside, mut n_out) = (0.0, 0, 0.0, 0);
        for x in 0..w {
            for y in 0..h {
                let p = apply_affine(&tau, &Point2::new(x as Real, y as Real));
                let value = Real::from(result.sparse[(x * h + y, column)].abs());
                let within = p.x >= x0 as Real
                    && p.x < (x0 + size) as Real
                    && p.y >= y0 as Real
                    && p.y < (y0 + size) as Real;
                if within {
                    inside += value;
                    n_in += 1;
                } else {
                    outside += value;
                    n_out += 1;
                }
            }
        }
        let (inside, outside) = (inside / n_in.max(1) as Real, outside / n_out as Real);
        assert!(n_in > 50, "the block should be in the window");
        assert!(
            inside > 5.0 * outside,
            "copy {i}: |E| {inside} inside vs {outside} outside"
        );
    }
    // The pictures decode, and the mean window is sharper after alignment than before.
    let images = result.images().unwrap();
    let names: Vec<&str> = images.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "before.png",
            "aligned.png",
            "low-rank.png",
            "sparse.png",
            "mean-before.png",
            "mean-after.png"
        ]
    );
    let sharpness = |bytes: &[u8]| -> Real {
        let image = image::load_from_memory(bytes).unwrap().to_luma8();
        assert_eq!((image.width(), image.height()), (100, 120));
        let mut energy = 0.0;
        for y in 0..120 {
            for x in 1..100 {
                let d = Real::from(image.get_pixel(x, y)[0]) - Real::from(image.get_pixel(x - 1, y)[0]);
                energy += d * d;
            }
        }
        energy
    };
    let (blurred, sharp) = (sharpness(&images[4].1), sharpness(&images[5].1));
    assert!(
        sharp > 1.2 * blurred,
        "mean gradient energy {blurred} before, {sharp} after"
    );
    // The warps do not shrink: the mean warp keeps its starting scale.
    let scale = |warps: &[Matrix2x3<Real>]| -> Real {
        warps
            .iter()
            .map(|m| m.fixed_view::<2, 2>(0, 0).determinant().abs().sqrt())
            .sum::<Real>()
            / warps.len() as Real
    };
    let ratio = scale(&result.warps) / scale(&result.initial_warps);
    assert!((ratio - 1.0).abs() < 0.03, "mean scale changed by {ratio}");
}

#[test]
fn gram_thresholding_matches_a_full_svd() {
    let mut rng = Lcg(9);
    let (d, n) = (300, 12);
    // Rank 3 plus small noise.
    let u = DMatrix::<Real>::from_fn(d, 3, |_, _| rng.gaussian());
    let v = DMatrix::<Real>::from_fn(3, n, |_, _| rng.gaussian());
    let m: DMatrix<Real> = &u * &v + DMatrix::from_fn(d, n, |_, _| 0.01 * rng.gaussian());
    let m32 = m.map(|x| x as f32);
    for threshold in [0.5, 3.0, 20.0] {
        let (ours, nuclear, largest) = singular_value_threshold(&m32, threshold);
        let svd = m.clone().svd(true, true);
        let shrunk = svd.singular_values.map(|s| (s - threshold).max(0.0));
        let full = svd.u.unwrap() * DMatrix::from_diagonal(&shrunk) * svd.v_t.unwrap();
        let error = (ours.map(Real::from) - &full).norm() / full.norm().max(1e-12);
        assert!(error < 1e-4, "threshold {threshold}: relative error {error}");
        assert!((nuclear - shrunk.sum()).abs() < 1e-4 * shrunk.sum().max(1.0));
        assert!((largest - svd.singular_values.max()).abs() < 1e-4 * largest);
    }
}

#[test]
fn bad_photos_are_dropped_with_reasons_and_an_empty_batch_is_an_error() {
    let b = batch(3, 0.0, 1);
    let mut photos = b.photos.clone();
    // Points outside the image.
    let mut outside = photos[1].points.clone();
    outside.points[4].y = 500.0;
    outside.name = "outside".into();
    photos.push(RaslPhoto {
        image: photos[0].image.clone(),
        points: outside,
    });
    let result = rasl_frontal(&photos, &RaslOptions::default()).unwrap();
    assert_eq!(result.kept.len(), 3);
    assert_eq!(result.dropped.len(), 1);
    assert_eq!(result.dropped[0].name, "outside");
    assert!(
        result.dropped[0].reason.contains("point 4"),
        "{}",
        result.dropped[0].reason
    );
    assert_eq!(result.frontal.warps.len(), 3);

    let only_bad = vec![photos.pop().unwrap()];
    match rasl_frontal(&only_bad, &RaslOptions::default()) {
        Err(AlignError::Frontal { problem }) => assert!(problem.contains("outside"), "{problem}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        rasl_frontal(&[], &RaslOptions::default()).unwrap_err(),
        AlignError::NoPhotos
    );
    let tiny = RaslOptions {
        width: 4,
        ..RaslOptions::default()
    };
    assert!(rasl_frontal(&b.photos, &tiny).is_err());
}

#[test]
fn images_are_validated() {
    assert_eq!(GreyImage::new(0, 10, vec![]).unwrap_err(), PhotoProblem::Empty);
    assert!(matches!(
        GreyImage::new(20, 20, vec![0.5; 400]),
        Err(PhotoProblem::Tiny { .. })
    ));
    assert_eq!(
        GreyImage::new(40, 40, vec![0.5; 1600]).unwrap_err(),
        PhotoProblem::Flat
    );
    let mut data = vec![0.5; 1600];
    data[3] = f32::NAN;
    assert_eq!(
        GreyImage::new(40, 40, data).unwrap_err(),
        PhotoProblem::NonFinite(3)
    );
    assert!(matches!(
        GreyImage::new(40, 40, vec![0.5; 10]),
        Err(PhotoProblem::SizeMismatch { .. })
    ));
    // Files: missing, not an image, decoded but tiny.
    let dir = std::env::temp_dir().join(format!("splineface-rasl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let missing = GreyImage::read(&dir.join("missing.jpg")).unwrap_err();
    assert!(missing.to_string().contains("missing.jpg"));
    std::fs::write(dir.join("text.png"), "not an image").unwrap();
    let garbage = GreyImage::read(&dir.join("text.png")).unwrap_err();
    assert!(
        matches!(garbage.problem, PhotoProblem::Unreadable(_)),
        "{garbage}"
    );
    image::GrayImage::from_fn(16, 16, |x, _| image::Luma([x as u8 * 10]))
        .save(dir.join("tiny.png"))
        .unwrap();
    let tiny = GreyImage::read(&dir.join("tiny.png")).unwrap_err();
    assert!(matches!(tiny.problem, PhotoProblem::Tiny { .. }), "{tiny}");
    let (face, _) = face_photo(64, 80);
    let bytes: Vec<u8> = face.data().iter().map(|v| (v * 255.0) as u8).collect();
    image::GrayImage::from_raw(64, 80, bytes)
        .unwrap()
        .save(dir.join("face.png"))
        .unwrap();
    let read = GreyImage::read(&dir.join("face.png")).unwrap();
    assert_eq!((read.width(), read.height()), (64, 80));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn rasl_feeds_the_depth_stage() {
    use splineface::depth::{DepthOptions, Pose, StructurePrior, estimate_depth};
    use splineface::structure::correlation;
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let mesh = face.mesh(&MeshOptions { spacing: 1.0 }).unwrap().mesh;
    let mut rng = Lcg(8);
    let mut photos = Vec::new();
    let mut poses = Vec::new();
    for k in 0..10 {
        let (yaw, pitch, roll) = (
            rng.uniform(-35.0, 35.0),
            rng.uniform(-15.0, 15.0),
            rng.uniform(-10.0, 10.0),
        );
        let view = View::from_yaw_pitch_roll_degrees(yaw, pitch, roll);
        let photo = synthetic_photo(&mesh, r.structure(), &view, 200, 240, 0.12).unwrap();
        photos.push(RaslPhoto {
            image: Cow::Owned(photo.image),
            points: PhotoPoints::new(format!("p{k}"), photo.points).unwrap(),
        });
        poses.push(Pose::from_yaw_pitch_roll_degrees(yaw, pitch, roll, 1.0));
    }
    let result = rasl_frontal(&photos, &RaslOptions::default()).unwrap();
    let points: Vec<PhotoPoints> = photos.iter().map(|p| p.points.clone()).collect();
    let prior = StructurePrior::from_reference(r);
    let estimate = estimate_depth(&points, &result.frontal, &prior, &DepthOptions::default()).unwrap();
    let depths = |ps: &[nalgebra::Point3<Real>]| ps.iter().map(|p| p.z).collect::<Vec<_>>();
    let r_depth = correlation(&depths(&estimate.structure), &depths(r.structure())).unwrap();
    assert!(r_depth > 0.999, "depth correlation {r_depth}");
    for (fit, pose) in estimate.photos.iter().zip(&poses) {
        let error = fit.pose.angle_to_degrees(pose);
        assert!(error < 1.5, "{}: {error}°", fit.name);
    }
}
