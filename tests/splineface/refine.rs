//! The dense refinement against photos rendered from a known member of the face space.

use nalgebra::{Point2, Point3, Vector3};
use splineface::Real;
use splineface::align::{GreyImage, PhotoPoints};
use splineface::compare::fit_similarity;
use splineface::face::{
    FaceError, FaceSpace, MeshOptions, PhotoFitOptions, PhotoSpaceFit, RefineOptions, RefineView, Refinement,
    Window,
};
use splineface::mesh::{TextureCoordinates, TriangleMesh};
use splineface::reference::ReferenceFace;
use splineface::render::{Camera, ColourMap, Lighting, PhotoLook, render_photo};
use splineface::structure::contour_weighted;

use crate::common::Lcg;

/// A skin-like texture over `(u, v)`: smooth blotches at several scales and dark spots, so
/// that every level of the refinement has something to match.
fn texture(seed: u64) -> image::RgbImage {
    let mut rng = Lcg(seed);
    let blobs: Vec<(Real, Real, Real, Real)> = (0..400)
        .map(|k| {
            let size = if k < 40 {
                0.04
            } else if k < 160 {
                0.015
            } else {
                0.006
            };
            (
                rng.next(),
                rng.next(),
                size * rng.uniform(0.6, 1.4),
                rng.uniform(-0.5, 0.5),
            )
        })
        .collect();
    image::RgbImage::from_fn(384, 384, |x, y| {
        let (u, v) = (x as Real / 383.0, y as Real / 383.0);
        let mut value = 0.6;
        for &(cu, cv, size, amplitude) in &blobs {
            let d2 = ((u - cu).powi(2) + (v - cv).powi(2)) / (size * size);
            if d2 < 9.0 {
                value += amplitude * (-0.5 * d2).exp();
            }
        }
        let c = (255.0 * value.clamp(0.05, 0.95)) as u8;
        image::Rgb([c, (0.8 * c as Real) as u8, (0.7 * c as Real) as u8])
    })
}

struct Scene {
    reference: &'static ReferenceFace,
    height: Real,
    space: FaceSpace,
    truth: Vec<Real>,
    images: Vec<GreyImage>,
    views: Vec<Vec<Point2<Real>>>,
}

/// Three photos (yaw −25°, 0°, 25°, each lit from another side) of the space's member with
/// weights `truth`, under perspective cameras 700 units away, with the member's 40 points
/// projected and jittered by 1.5 pixels as the landmarks.
fn scene(truth_sigmas: &[Real]) -> Scene {
    scene_with_bump(truth_sigmas, 0.0)
}

/// The cheek bump of [`scene_with_bump`]: its height at a point of the canonical frame.
fn bump(p: &Point3<Real>, height: Real) -> Real {
    let d2 = (p.x - 30.0).powi(2) + (p.y + 35.0).powi(2);
    height * (-d2 / (2.0 * 10.0 * 10.0)).exp()
}

/// As [`scene`], the member's surface raised by `height` units in a round bump on its left
/// cheek (outside what the space can express).
fn scene_with_bump(truth_sigmas: &[Real], height: Real) -> Scene {
    scene_with(truth_sigmas, height, &[])
}

/// As [`scene_with_bump`], each photo showing the member with its own expression weights
/// (`expressions[i]` for photo `i`, one per expression mode; none: every photo neutral).
fn scene_with(truth_sigmas: &[Real], height: Real, expressions: &[Vec<Real>]) -> Scene {
    let reference = ReferenceFace::embedded();
    let seen = reference.as_seen_in_photos().into_owned();
    let space = seen
        .face_space()
        .expect("the embedded reference has a face space");
    let truth: Vec<Real> = (0..space.mode_count())
        .map(|k| truth_sigmas.get(k).copied().unwrap_or(0.0) * space.sigma()[k])
        .collect();
    let mesh_with = |expression: &[Real]| {
        let face = space.face_with_expression(&seen, &truth, expression).unwrap();
        let clipped = face.mesh(&MeshOptions::default()).unwrap();
        let triangles = clipped.mesh.triangles().to_vec();
        let positions = clipped
            .mesh
            .positions()
            .iter()
            .map(|p| p + Vector3::z() * bump(p, height))
            .collect();
        TriangleMesh::new(positions, triangles.clone())
            .unwrap()
            .with_texture(TextureCoordinates {
                uvs: clipped.params.clone(),
                triangles,
            })
            .unwrap()
    };
    let neutral = mesh_with(&[]);
    let map = ColourMap::new(&texture(7));
    let mut rng = Lcg(11);
    let mut images = Vec::new();
    let mut views = Vec::new();
    for (i, (yaw, light)) in [
        (-25.0, [0.4, 0.3, 1.0]),
        (0.0, [-0.3, 0.5, 1.0]),
        (25.0, [0.0, -0.2, 1.0]),
    ]
    .into_iter()
    .enumerate()
    {
        let expression = expressions.get(i).map_or(&[][..], Vec::as_slice);
        let expressive = (!expression.is_empty()).then(|| mesh_with(expression));
        let mesh = expressive.as_ref().unwrap_or(&neutral);
        let structure = space.structure_with_expression(&truth, expression).unwrap();
        let camera = Camera::looking_at_head(
            [yaw, 4.0, 2.0],
            &Point3::new(0.0, -20.0, 10.0),
            700.0,
            1400.0,
            (420, 520),
        );
        let lighting = Lighting::matte(Vector3::from(light), 0.6, 0.4);
        let look = PhotoLook {
            background_top: [0.3; 3],
            background_bottom: [0.5; 3],
            blur: 0.5,
            seed: 3,
            supersampling: 2,
            ..PhotoLook::default()
        };
        let photo = render_photo(mesh, &map, &camera, &lighting, &look).unwrap();
        images.push(GreyImage::from_dynamic(&image::DynamicImage::ImageRgb8(photo)).unwrap());
        let points: Vec<Point2<Real>> = structure
            .iter()
            .map(|p| {
                let q = camera.project(p).unwrap();
                Point2::new(q.x + 1.5 * rng.gaussian(), q.y + 1.5 * rng.gaussian())
            })
            .collect();
        views.push(PhotoPoints::new(format!("yaw {yaw}"), points).unwrap().y_up());
    }
    Scene {
        reference: &*Box::leak(Box::new(seen)),
        height,
        space,
        truth,
        images,
        views,
    }
}

/// RMS distance between the members `a` and `b` over the face region, after the similarity
/// that best maps one onto the other.
fn shape_distance(scene: &Scene, a: &[Real], b: &[Real]) -> Real {
    distance_to_truth(scene, a, &[], b, false).0
}

/// RMS distance between the member `a` with its control points moved by `displacement` and
/// the member `b` (with the scene's bump when `bumped`), as [`shape_distance`]: over the
/// face region, and over the bump (where it is over a fifth of its height).
fn distance_to_truth(
    scene: &Scene,
    a: &[Real],
    displacement: &[Vector3<Real>],
    b: &[Real],
    bumped: bool,
) -> (Real, Real) {
    let mut params = Vec::new();
    for i in 0..40 {
        for j in 0..40 {
            let (u, v) = ((i as Real + 0.5) / 40.0, (j as Real + 0.5) / 40.0);
            if scene.reference.in_face_region(u, v) {
                params.push([u, v]);
            }
        }
    }
    let points = |w: &[Real], displacement: &[Vector3<Real>]| {
        let face = scene.space.face(scene.reference, w).unwrap();
        let face = if displacement.is_empty() {
            face
        } else {
            face.displaced(displacement).unwrap()
        };
        let surface = face.surface();
        surface.eval_many(&params).unwrap()
    };
    let pa = points(a, displacement);
    let mut pb = points(b, &[]);
    if bumped {
        for p in &mut pb {
            p.z += bump(p, scene.height);
        }
    }
    let (map, _) = fit_similarity(&pa, &pb).unwrap();
    let squares: Vec<(Real, bool)> = pa
        .iter()
        .zip(&pb)
        .map(|(p, q)| ((map * p - q).norm_squared(), bump(q, 1.0) > 0.2))
        .collect();
    let rms = |near: bool| {
        let kept: Vec<Real> = squares
            .iter()
            .filter(|(_, b)| *b || !near)
            .map(|(d, _)| *d)
            .collect();
        (kept.iter().sum::<Real>() / kept.len().max(1) as Real).sqrt()
    };
    (rms(false), rms(true))
}

/// The landmark fit the refinement starts from (the pipeline's point weights and noise, every
/// photo neutral), and the photos as the refinement takes them.
fn landmark_fit(scene: &Scene) -> ([Real; 40], PhotoSpaceFit, Vec<RefineView<'_>>) {
    let weights = contour_weighted(0.1);
    let fit = scene
        .space
        .fit_photos(
            &scene.views,
            &weights,
            &PhotoFitOptions {
                noise: 4.0,
                expressions: None,
                outline: false,
                lips: splineface::face::LIP_WEIGHT,
            },
        )
        .unwrap();
    let views = scene
        .images
        .iter()
        .zip(&scene.views)
        .map(|(image, points)| RefineView { image, points })
        .collect();
    (weights, fit, views)
}

/// `scene` refined with `options` from its landmark fit.
fn refined(scene: &Scene, options: &RefineOptions) -> Refinement {
    let (weights, fit, views) = landmark_fit(scene);
    scene
        .space
        .refine_photos(scene.reference, &fit, &views, &weights, options)
        .unwrap()
}

/// Every way of making the photos comparable (the window in the image, the shading divided
/// out before a window on the surface, and the photos compared with the face lit) pulls the
/// face toward the member the photos show, each photo lit from another side.
#[test]
fn the_photos_pull_the_face_toward_the_member_they_show() {
    let scene = scene(&[1.5, -1.5, 1.0, -1.0, 1.5, 1.0, -1.5, 1.0, 1.0, -1.0, 0.8, -0.8]);
    let (_, fit, _) = landmark_fit(&scene);
    let before = shape_distance(&scene, &fit.weights, &scene.truth);
    let mean = shape_distance(&scene, &vec![0.0; scene.truth.len()], &scene.truth);
    for window in [Window::Image, Window::Shaded, Window::Lit] {
        let options = RefineOptions {
            window,
            ..RefineOptions::default()
        };
        let refined = refined(&scene, &options);
        let after = shape_distance(&scene, &refined.weights, &scene.truth);
        eprintln!(
            "{window:?}: shape distance: mean face {mean:.3}, landmark fit {before:.3}, refined {after:.3}; {}",
            refined.note
        );
        assert!(refined.accepted, "{window:?}: {}", refined.note);
        assert!(
            refined.disagreement.1 < 0.8 * refined.disagreement.0,
            "{window:?}: the photos agree better: {:?}",
            refined.disagreement
        );
        assert!(
            after < 0.7 * before,
            "{window:?}: the refined face is nearer the member: {after:.3} against the landmark fit's {before:.3} (the mean face {mean:.3}) units"
        );
        // The cameras are 700 units away (the focal length 2.7 times the photos' longer side,
        // where the prior expects 1.2): their distances come out within a factor of 1.5.
        let distances: Vec<Real> = refined.cameras.iter().map(|c| 1.0 / c.perspective).collect();
        eprintln!("{window:?}: camera distances {distances:?}");
        assert!(
            distances.iter().all(|d| (700.0 / 1.5..700.0 * 1.5).contains(d)),
            "{window:?}: camera distances {distances:?}, 700 units in truth"
        );
        assert_eq!(refined.coverage.len(), 3);
        assert!(
            refined.coverage.iter().all(|&c| c > 0.5),
            "{:?}",
            refined.coverage
        );
    }
}

/// A refinement that is turned down gives back the landmark fit as it stands: its weights, its
/// scaled orthographic cameras (not the typical perspective the refinement started from),
/// and the landmark RMS measured on them.
#[test]
fn a_refinement_turned_down_gives_back_the_landmark_fit() {
    let scene = scene(&[1.5, -1.0, 1.0]);
    let (weights, fit, views) = landmark_fit(&scene);
    let options = RefineOptions {
        levels: 1,
        min_gain: 1.0,
        ..RefineOptions::default()
    };
    let refined = scene
        .space
        .refine_photos(scene.reference, &fit, &views, &weights, &options)
        .unwrap();
    assert!(!refined.accepted, "{}", refined.note);
    assert_eq!(refined.share, 0.0);
    assert_eq!(refined.weights, fit.weights);
    for (camera, (pose, offset)) in refined.cameras.iter().zip(&fit.poses) {
        assert_eq!(camera.perspective, 0.0);
        assert_eq!(camera.rotation, pose.rotation);
        assert_eq!(camera.scale, pose.scale);
        assert_eq!(camera.offset, offset.coords);
    }
    // The same landmark RMS as a refinement whose cameras stay orthographic throughout.
    let orthographic = scene
        .space
        .refine_photos(
            scene.reference,
            &fit,
            &views,
            &weights,
            &RefineOptions {
                perspective: false,
                ..options
            },
        )
        .unwrap();
    assert_eq!(refined.landmark_rms.0, orthographic.landmark_rms.0);
    assert!(refined.disagreement.0 <= orthographic.disagreement.0);
}

/// With the face held only the cameras move: the weights stay the fit's to the bit however far
/// the photos' disagreement falls, and the cameras leave the fit's orthographic poses.
#[test]
fn holding_the_face_refines_the_cameras_alone() {
    let scene = scene(&[1.5, -1.0, 1.0]);
    let (weights, fit, views) = landmark_fit(&scene);
    let run = |hold_face| {
        let options = RefineOptions {
            levels: 1,
            min_gain: Real::NEG_INFINITY,
            hold_face,
            ..RefineOptions::default()
        };
        scene
            .space
            .refine_photos(scene.reference, &fit, &views, &weights, &options)
            .unwrap()
    };
    let held = run(true);
    assert!(held.accepted, "{}", held.note);
    assert_eq!(held.weights, fit.weights);
    assert!(
        held.disagreement.1 <= held.disagreement.0,
        "{:?}",
        held.disagreement
    );
    assert!(
        held.cameras
            .iter()
            .zip(&fit.poses)
            .any(|(camera, (pose, offset))| camera.perspective != 0.0
                || camera.rotation != pose.rotation
                || camera.offset != offset.coords),
        "no camera moved"
    );
    // Not held, the same refinement moves the face.
    assert_ne!(run(false).weights, fit.weights);
}

/// A fall of the disagreement short of `full_gain` keeps that share of the way from the landmark
/// fit to the refined face: the weights on the segment between the two, exactly, with the
/// refined cameras.
#[test]
fn a_refinement_kept_in_part_lies_between_the_landmark_fit_and_the_refined_face() {
    let scene = scene(&[1.5, -1.5, 1.0, -1.0, 1.5, 1.0]);
    let (weights, fit, views) = landmark_fit(&scene);
    let refine = |min_gain, full_gain| {
        let options = RefineOptions {
            levels: 2,
            min_gain,
            full_gain,
            ..RefineOptions::default()
        };
        scene
            .space
            .refine_photos(scene.reference, &fit, &views, &weights, &options)
            .unwrap()
    };
    let whole = refine(Real::NEG_INFINITY, 0.0);
    assert!(whole.accepted && whole.share == 1.0, "{}", whole.note);
    // A ramp from -1 to 10: the share is a tenth or so, whatever the fall.
    let part = refine(-1.0, 10.0);
    let gain = 1.0 - part.disagreement.1 / part.disagreement.0;
    eprintln!("fall {gain:.3}, share {:.3}: {}", part.share, part.note);
    assert_eq!(
        part.disagreement, whole.disagreement,
        "the same refinement before the verdict"
    );
    assert!(part.accepted);
    assert!((part.share - (gain + 1.0) / 11.0).abs() < 1e-12, "{}", part.share);
    assert!(
        part.note.contains("of the way from the landmark fit"),
        "{}",
        part.note
    );
    for ((p, f), w) in part.weights.iter().zip(&fit.weights).zip(&whole.weights) {
        let expected = f + part.share * (w - f);
        assert!((p - expected).abs() < 1e-9, "{p} against {expected}");
    }
    // The refined cameras are kept.
    for (a, b) in part.cameras.iter().zip(&whole.cameras) {
        assert_eq!((a.offset, a.rotation, a.scale), (b.offset, b.rotation, b.scale));
    }
    let between = shape_distance(&scene, &part.weights, &fit.weights);
    let all = shape_distance(&scene, &whole.weights, &fit.weights);
    assert!(between > 0.0 && between < all, "{between} of {all}");
}

/// The check on photos left out: on photos of a member of the space, the face the other
/// photos refine predicts each left-out photo better than the landmark fit's face, and a
/// threshold the check cannot meet turns the refinement down with the landmark fit standing.
#[test]
fn photos_left_out_agree_better_with_a_face_the_others_refined() {
    let scene = scene(&[1.5, -1.5, 1.0, -1.0, 1.5, 1.0, -1.5, 1.0, 1.0, -1.0, 0.8, -0.8]);
    let (weights, fit, views) = landmark_fit(&scene);
    let options = RefineOptions {
        held_out: true,
        min_held_out_gain: 0.0,
        ..RefineOptions::default()
    };
    let refine = |options: &RefineOptions| {
        scene
            .space
            .refine_photos(scene.reference, &fit, &views, &weights, options)
            .unwrap()
    };
    let refined = refine(&options);
    let (before, after) = refined.held_out.expect("three photos have folds");
    eprintln!("photos left out: {before:.3} → {after:.3}; {}", refined.note);
    assert!(refined.accepted, "{}", refined.note);
    // (The photos left out differ from the others in their light and the pixels' noise
    // whatever the face: their disagreement falls by a few percent where the others' falls by
    // a quarter.)
    assert!(after < 0.98 * before, "{before} → {after}");
    assert!(refined.note.contains("photos left out"), "{}", refined.note);
    // Without the check, no figure and the same face.
    let unchecked = refine(&RefineOptions {
        held_out: false,
        ..options
    });
    assert_eq!(unchecked.held_out, None);
    assert_eq!(unchecked.weights, refined.weights);
    let strict = refine(&RefineOptions {
        min_held_out_gain: 1.0,
        ..options
    });
    assert!(!strict.accepted);
    assert!(strict.note.contains("left out"), "{}", strict.note);
    assert_eq!(strict.weights, fit.weights);
    // Two photos have no folds: judged by the disagreement alone.
    let two = &views[..2];
    let fit_two = PhotoSpaceFit {
        poses: fit.poses[..2].to_vec(),
        expressions: fit.expressions.iter().take(2).cloned().collect(),
        rms_units: fit.rms_units.iter().take(2).copied().collect(),
        outline_shifts: fit.outline_shifts.iter().take(2).cloned().collect(),
        ..fit.clone()
    };
    let pair = scene
        .space
        .refine_photos(
            scene.reference,
            &fit_two,
            two,
            &weights,
            &RefineOptions {
                min_held_out_gain: 1.0,
                ..options
            },
        )
        .unwrap();
    assert_eq!(pair.held_out, None);
}

#[test]
fn refinement_refuses_views_that_do_not_match_the_fit_and_bad_options() {
    let scene = scene(&[1.0]);
    let (weights, fit, views) = landmark_fit(&scene);
    let refine = |views: &[RefineView], options: &RefineOptions| {
        scene
            .space
            .refine_photos(scene.reference, &fit, views, &weights, options)
    };
    assert!(matches!(
        refine(&views[..2], &RefineOptions::default()),
        Err(FaceError::Option { name: "views", .. })
    ));
    // The default options with one changed.
    let with = |change: fn(&mut RefineOptions)| {
        let mut options = RefineOptions::default();
        change(&mut options);
        options
    };
    for (options, name) in [
        (with(|o| o.levels = 0), "levels"),
        (with(|o| o.sigma = 0.0), "sigma"),
        (with(|o| o.beta = Real::NAN), "beta"),
        (with(|o| o.spacing = -1.0), "spacing"),
        (with(|o| o.full_gain = Real::NAN), "full gain"),
        (with(|o| o.window_eyes = 0.0), "window eyes"),
        (with(|o| o.field_levels = 0), "field levels"),
        (with(|o| o.field_bend = Real::INFINITY), "field bend"),
        (with(|o| o.field_sigma = -2.0), "field sigma"),
        (with(|o| o.expression_shift = Some(0.0)), "expression shift"),
        (
            with(|o| o.expression_photos = Some(Real::NAN)),
            "expression photos",
        ),
    ] {
        match refine(&views, &options) {
            Err(FaceError::Option { name: got, .. }) => assert_eq!(got, name),
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn the_displacement_field_follows_a_bump_the_space_cannot_express() {
    let scene = scene_with_bump(&[1.0, -1.0, 0.5], 4.0);
    let (weights, fit, views) = landmark_fit(&scene);
    let refine = |options: RefineOptions| {
        scene
            .space
            .refine_photos(scene.reference, &fit, &views, &weights, &options)
            .unwrap()
    };
    // The window the field was built and measured with, the field at every level: under the
    // lit measure its Jacobian leaves out how the field bends the normals, and it takes less
    // off the bump's error (below).
    let image = |field| RefineOptions {
        field,
        window: Window::Image,
        field_levels: usize::MAX,
        ..RefineOptions::default()
    };
    let (plain, with_field) = (refine(image(false)), refine(image(true)));
    let lit = |field| {
        refine(RefineOptions {
            field,
            ..RefineOptions::default()
        })
    };
    let (lit_plain, lit_field) = (lit(false), lit(true));
    let lit_errors = [&lit_plain, &lit_field]
        .map(|r| distance_to_truth(&scene, &r.weights, &r.displacement, &scene.truth, true));
    eprintln!(
        "bump, the default options: without the field {:.3?}, with it {:.3?} units (face, bump)",
        lit_errors[0], lit_errors[1]
    );
    // Measured: 0.76 of the bump's error, the face's 0.81.
    assert!(
        lit_errors[1].1 < 0.85 * lit_errors[0].1 && lit_errors[1].0 < lit_errors[0].0,
        "the default's field follows the bump too: {:.3?} against {:.3?} without it",
        lit_errors[1],
        lit_errors[0]
    );
    assert!(plain.displacement.is_empty());
    assert!(with_field.accepted, "{}", with_field.note);
    let plain_error = distance_to_truth(&scene, &plain.weights, &[], &scene.truth, true);
    let field_error = distance_to_truth(
        &scene,
        &with_field.weights,
        &with_field.displacement,
        &scene.truth,
        true,
    );
    let highest = with_field.displacement.iter().map(|d| d.z).fold(0.0, Real::max);
    eprintln!(
        "bump: weights only {plain_error:.3?}, with the field {field_error:.3?} units (face, bump; highest control point moved {highest:.2})"
    );
    assert!(
        field_error.1 < 0.6 * plain_error.1,
        "the field follows the bump: {:.3} against {:.3} units without it",
        field_error.1,
        plain_error.1
    );
    assert!(
        field_error.0 < plain_error.0,
        "and does not spoil the rest of the face: {:.3} against {:.3} units",
        field_error.0,
        plain_error.0
    );
}

/// The distance from the truth of `scene`'s refinement under `window`, with or without
/// [`RefineOptions::photo_weights`].
fn refined_distance(scene: &Scene, window: Window, photo_weights: bool) -> Real {
    let options = RefineOptions {
        photo_weights,
        min_gain: Real::NEG_INFINITY,
        window,
        ..RefineOptions::default()
    };
    shape_distance(scene, &refined(scene, &options).weights, &scene.truth)
}

/// `scene` with a fourth photo that disagrees with the others for reasons other than shape:
/// the frontal photo with its intensities inverted, as under another kind of light or make-up.
fn with_an_inverted_photo(mut scene: Scene) -> Scene {
    let frontal = &scene.images[1];
    let inverted = GreyImage::new(
        frontal.width(),
        frontal.height(),
        frontal.data().iter().map(|v| 1.0 - v).collect(),
    )
    .unwrap();
    scene.images.push(inverted);
    scene.views.push(scene.views[1].clone());
    scene
}

/// The inverted photo pulls the refinement off the face the three good photos give;
/// weighing each photo by its agreement with the others (`RefineOptions::photo_weights`)
/// takes back most of the difference, with the window the weights were built and measured
/// with (under the lit measure they do not help yet: `RefineOptions::photo_weights`).
#[test]
fn a_photo_that_disagrees_with_the_others_counts_less() {
    let scene = scene(&[1.5, -1.5, 1.0, -1.0, 1.5, 1.0, -1.5, 1.0, 1.0, -1.0, 0.8, -0.8]);
    let good = refined_distance(&scene, Window::Image, false);
    let scene = with_an_inverted_photo(scene);
    let (plain, weighted) = (
        refined_distance(&scene, Window::Image, false),
        refined_distance(&scene, Window::Image, true),
    );
    eprintln!("the three good photos {good:.3}; with the bad one {plain:.3}, weighted {weighted:.3}");
    assert!(
        plain > good + 0.02,
        "the bad photo pulls the face off: {plain:.3} against {good:.3}"
    );
    assert!(
        weighted - good < 0.5 * (plain - good),
        "photo weights take back most of it: {weighted:.3} (without {plain:.3}, the good photos alone {good:.3})"
    );
}

/// Under the lit measure each photo's light is fitted at full weight, whatever the photo's
/// weight: fitted at the weights, a down-weighted photo's light was all but free, and the
/// weighted refinements of these five faces with an inverted photo ended 1.46 units from the
/// truth on average (one 2.38) against 0.91 unweighted; now 1.00 (the largest 1.41). Five
/// faces, since one refinement moved by 0.07 with a change in the last bit of its input.
#[test]
fn under_the_lit_measure_a_photos_weight_leaves_its_light_alone() {
    let (mut plain, mut weighted) = (Vec::new(), Vec::new());
    for seed in 101..106 {
        let mut rng = Lcg(seed);
        let truth: Vec<Real> = (0..12).map(|_| rng.gaussian()).collect();
        let scene = with_an_inverted_photo(scene(&truth));
        plain.push(refined_distance(&scene, Window::Lit, false));
        weighted.push(refined_distance(&scene, Window::Lit, true));
    }
    let mean = |v: &[Real]| v.iter().sum::<Real>() / v.len() as Real;
    eprintln!("unweighted {plain:.3?}, weighted {weighted:.3?}");
    assert!(
        mean(&weighted) < mean(&plain) + 0.2,
        "weighted {weighted:.3?} against unweighted {plain:.3?}"
    );
    assert!(weighted.iter().all(|&d| d < 1.6), "{weighted:.3?}");
}

/// Each photo's own expression shift ([`RefineOptions::expression_photos`]) takes up an
/// expression the landmark fit under-read. The middle of three photos opens the jaw (0.5) and
/// the fit the refinement starts from gives it half of that: refined with the shifts, that
/// photo's jaw comes most of the way to the truth and the neutral photos' stay near closed;
/// without them every photo keeps the fit's expression.
#[test]
fn each_photos_own_shift_takes_up_the_expression_its_pixels_show() {
    let probe = scene(&[]);
    let names = probe.space.expressions().names.clone();
    let jaw = names
        .iter()
        .position(|n| n == "jawOpen")
        .expect("the space opens its jaw");
    let photo = |i: usize, weight: Real| {
        let mut e = vec![vec![0.0; names.len()]; 3];
        e[i][jaw] = weight;
        e
    };
    let scene = scene_with(&[1.0, -1.0, 0.5, 1.0, -0.5], 0.0, &photo(1, 0.5));
    let (weights, mut fit, views) = landmark_fit(&scene);
    fit.expressions = photo(1, 0.25);
    fit.expression_names = names;
    let refine = |expression_photos| {
        let options = RefineOptions {
            expression_photos,
            ..RefineOptions::default()
        };
        scene
            .space
            .refine_photos(scene.reference, &fit, &views, &weights, &options)
            .unwrap()
    };
    let held = refine(None);
    assert_eq!(held.expressions, fit.expressions);
    let shifted = refine(Some(0.5));
    let found: Vec<Real> = shifted.expressions.iter().map(|e| e[jaw]).collect();
    eprintln!(
        "jaw weights found {found:.3?} (truth 0, 0.5, 0); accepted {}",
        shifted.accepted
    );
    assert!(shifted.accepted, "{}", shifted.note);
    assert!((found[1] - 0.5).abs() < 0.1, "the open jaw: {found:.3?}");
    assert!(found[0] < 0.1 && found[2] < 0.1, "the closed jaws: {found:.3?}");
}
