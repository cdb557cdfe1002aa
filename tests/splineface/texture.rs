//! The texture atlas against photos rendered from a face whose colours are known.

use nalgebra::{Point3, Vector3};
use splineface::Real;
use splineface::face::{
    AUTOMATIC_MAX_SIDE, AUTOMATIC_MIN_SIDE, FaceError, FaceSurface, FaceTexture, MeshOptions, RefinedCamera,
    TexelSource, TextureOptions, TexturePhoto, automatic_atlas_side, bake_texture,
};
use splineface::reference::ReferenceFace;
use splineface::render::{Camera, ColourMap, Lighting, PhotoLook, render_photo};

/// A pattern symmetric in `u` (so that a face's mirror image carries the same colours):
/// stripes across `v`, rings about the midline, two hues.
fn pattern(u: Real, v: Real) -> [u8; 3] {
    let x = (u - 0.5).abs();
    let a = (0.5 + 0.4 * (v * 40.0).sin()) * 255.0;
    let b = (0.5 + 0.4 * (x * 55.0).cos()) * 255.0;
    [a as u8, b as u8, ((a + b) / 2.0) as u8]
}

fn pattern_image(side: u32) -> image::RgbImage {
    image::RgbImage::from_fn(side, side, |x, y| {
        image::Rgb(pattern(
            (Real::from(x) + 0.5) / Real::from(side),
            1.0 - (Real::from(y) + 0.5) / Real::from(side),
        ))
    })
}

fn mean_face() -> FaceSurface {
    let reference = ReferenceFace::embedded();
    let space = reference
        .face_space()
        .expect("the embedded reference has a face space");
    space.face(reference, &vec![0.0; space.mode_count()]).unwrap()
}

/// Photos of `face` textured with [`pattern`], lit by ambient light of strength `exposure`
/// alone (no blur, no noise), so that each pixel is the pattern's colour at what it sees
/// times `exposure` (in linear light).
fn photos(face: &FaceSurface, views: &[(Real, Real)]) -> Vec<(image::RgbImage, RefinedCamera)> {
    let clipped = face.mesh(&MeshOptions::default()).unwrap();
    let mesh = clipped.parameter_textured();
    let map = ColourMap::new(&pattern_image(1024));
    views
        .iter()
        .map(|&(yaw, exposure)| {
            let camera = Camera::looking_at_head(
                [yaw, 5.0, 0.0],
                &Point3::new(0.0, -20.0, 10.0),
                600.0,
                1500.0,
                (500, 600),
            );
            let lighting = Lighting::matte(Vector3::z(), 0.0, exposure);
            let look = PhotoLook {
                blur: 0.0,
                noise: 0.0,
                supersampling: 2,
                ..PhotoLook::default()
            };
            let image = render_photo(&mesh, &map, &camera, &lighting, &look).unwrap();
            (image, RefinedCamera::from_pinhole(&camera).unwrap())
        })
        .collect()
}

fn bake(
    face: &FaceSurface,
    shots: &[(image::RgbImage, RefinedCamera)],
    options: &TextureOptions,
) -> FaceTexture {
    let photos: Vec<TexturePhoto> = shots
        .iter()
        .map(|(image, camera)| TexturePhoto {
            image,
            camera: *camera,
            surface: None,
        })
        .collect();
    bake_texture(face, &photos, options).unwrap()
}

/// Per texel of `source`: the mean absolute error (0–255 per channel) of the atlas against
/// the pattern.
fn errors_over(texture: &FaceTexture, source: TexelSource) -> Vec<Real> {
    let side = texture.atlas.width();
    let mut errors = Vec::new();
    for y in 0..side {
        for x in 0..side {
            if texture.sources[(y * side + x) as usize] != source {
                continue;
            }
            let truth = pattern(
                (Real::from(x) + 0.5) / Real::from(side),
                1.0 - (Real::from(y) + 0.5) / Real::from(side),
            );
            let got = texture.atlas.get_pixel(x, y).0;
            errors.push(
                (0..3)
                    .map(|c| (Real::from(got[c]) - Real::from(truth[c])).abs())
                    .sum::<Real>()
                    / 3.0,
            );
        }
    }
    errors
}

/// The mean of [`errors_over`], and how many texels it covers.
fn error_over(texture: &FaceTexture, source: TexelSource) -> (Real, usize) {
    let errors = errors_over(texture, source);
    (
        errors.iter().sum::<Real>() / errors.len().max(1) as Real,
        errors.len(),
    )
}

#[test]
fn the_atlas_gives_back_the_colours_the_photos_saw() {
    let face = mean_face();
    let shots = photos(&face, &[(-35.0, 1.0), (0.0, 1.0), (35.0, 1.0)]);
    let options = TextureOptions {
        size: Some(256),
        ..TextureOptions::default()
    };
    let texture = bake(&face, &shots, &options);
    let [seen, mirrored, filled] = texture.counts();
    let (error, n) = error_over(&texture, TexelSource::Seen);
    // The pattern's stripes are 40 texels of the 1024² map apart, some 10 texels of this
    // atlas: a registration error of a fraction of a texel shows as a few levels.
    assert!(
        n == seen && seen > 30_000,
        "seen {seen}, mirrored {mirrored}, filled {filled}"
    );
    assert!(error < 4.0, "mean error {error:.2} levels over {n} seen texels");
    for g in &texture.gains {
        for c in g {
            assert!((c - 1.0).abs() < 0.02, "gains {:?}", texture.gains);
        }
    }
    // Every photo takes part.
    assert!(texture.shares.iter().all(|&s| s > 0.1), "{:?}", texture.shares);
}

#[test]
fn a_photo_takes_nothing_it_does_not_see_and_the_mirror_fills_the_rest() {
    // One photo from 65° to the side: the far cheek behind the nose is hidden from it.
    let face = mean_face();
    let shots = photos(&face, &[(65.0, 1.0)]);
    let options = TextureOptions {
        size: Some(256),
        ..TextureOptions::default()
    };
    let texture = bake(&face, &shots, &options);
    let [seen, mirrored, filled] = texture.counts();
    assert!(
        mirrored > 5_000,
        "seen {seen}, mirrored {mirrored}, filled {filled}"
    );
    // A hidden texel given the colour of what hides it is off by tens of levels. (Without
    // the depth test, 1,165 more texels count as seen and the mean error over the seen ones
    // triples.)
    let wrong = errors_over(&texture, TexelSource::Seen)
        .into_iter()
        .filter(|&e| e > 40.0)
        .count();
    assert!(
        wrong * 1000 < seen,
        "{wrong} of {seen} seen texels are off by over 40 levels"
    );
    let (seen_error, _) = error_over(&texture, TexelSource::Seen);
    assert!(seen_error < 2.0, "mean error {seen_error:.2} over seen texels");
    // The pattern is symmetric and so nearly is the face: mirrored texels are right too.
    let (mirror_error, _) = error_over(&texture, TexelSource::Mirrored);
    assert!(
        mirror_error < 2.0,
        "mean error {mirror_error:.2} over mirrored texels"
    );
    // Without the depth test's verdicts the hidden texels would have been given the nose's
    // colours: the same photo with the mirror off leaves them to diffusion, never to the photo.
    let plain = bake(
        &face,
        &shots,
        &TextureOptions {
            mirror: false,
            ..options
        },
    );
    assert_eq!(plain.counts()[0], seen);
    assert_eq!(plain.counts()[1], 0);
}

#[test]
fn photos_of_another_exposure_are_matched() {
    let face = mean_face();
    // The middle photo is exposed at 60%: a gain of 1/0.6 in linear light brings it back.
    let shots = photos(&face, &[(-30.0, 1.0), (0.0, 0.6), (30.0, 1.0)]);
    let options = TextureOptions {
        size: Some(256),
        ..TextureOptions::default()
    };
    let texture = bake(&face, &shots, &options);
    for c in 0..3 {
        let ratio = texture.gains[1][c] / texture.gains[0][c];
        assert!((ratio - 1.0 / 0.6).abs() < 0.03, "channel {c}: ratio {ratio:.3}");
        let other = texture.gains[2][c] / texture.gains[0][c];
        assert!((other - 1.0).abs() < 0.02, "channel {c}: ratio {other:.3}");
    }
    // Unmatched, the dark photo darkens the blend where it counts (most where it is the
    // best view); matched, the atlas is the pattern up to one common factor.

    let unmatched = bake(
        &face,
        &shots,
        &TextureOptions {
            match_colours: false,
            ..options
        },
    );
    let spread = |t: &FaceTexture| {
        // The spread of the atlas's ratio to the pattern (green channel, linear light) over
        // the seen texels: 0 when it is the pattern times one factor.
        let side = t.atlas.width();
        let linear = |v: u8| Real::from(splineface::render::srgb_to_linear(f32::from(v) / 255.0));
        let ratios: Vec<Real> = (0..side * side)
            .filter(|&k| t.sources[k as usize] == TexelSource::Seen)
            .filter_map(|k| {
                let (x, y) = (k % side, k / side);
                let truth = pattern(
                    (Real::from(x) + 0.5) / Real::from(side),
                    1.0 - (Real::from(y) + 0.5) / Real::from(side),
                );
                (truth[1] > 60).then(|| linear(t.atlas.get_pixel(x, y).0[1]) / linear(truth[1]))
            })
            .collect();
        let mean = ratios.iter().sum::<Real>() / ratios.len() as Real;
        (ratios.iter().map(|r| (r - mean).powi(2)).sum::<Real>() / ratios.len() as Real).sqrt() / mean
    };
    // The floor: the same views all exposed alike (resampling the stripes twice, in the
    // renderer and in the atlas, spreads the ratio a little).
    let alike = bake(
        &face,
        &photos(&face, &[(-30.0, 1.0), (0.0, 1.0), (30.0, 1.0)]),
        &options,
    );
    let (matched, plain, floor) = (spread(&texture), spread(&unmatched), spread(&alike));
    assert!(
        matched < 1.2 * floor,
        "matched spread {matched:.3} against {floor:.3} with every photo exposed alike"
    );
    assert!(
        plain > 1.4 * matched,
        "unmatched spread {plain:.3} against matched {matched:.3}"
    );
}

#[test]
fn photos_of_other_sizes_register_and_a_grey_photo_gives_no_grey() {
    let face = mean_face();
    let mut shots = photos(&face, &[(-35.0, 1.0), (0.0, 1.0), (35.0, 1.0)]);
    // The frontal photo twice as large (the same camera at twice the focal length and size).
    let clipped = face.mesh(&MeshOptions::default()).unwrap();
    let mesh = clipped.parameter_textured();
    let camera = Camera::looking_at_head(
        [0.0, 5.0, 0.0],
        &Point3::new(0.0, -20.0, 10.0),
        600.0,
        3000.0,
        (1000, 1200),
    );
    let look = PhotoLook {
        blur: 0.0,
        noise: 0.0,
        supersampling: 1,
        ..PhotoLook::default()
    };
    let large = render_photo(
        &mesh,
        &ColourMap::new(&pattern_image(1024)),
        &camera,
        &Lighting::matte(Vector3::z(), 0.0, 1.0),
        &look,
    )
    .unwrap();
    shots[1] = (large, RefinedCamera::from_pinhole(&camera).unwrap());
    // The right-hand photo in grey.
    shots[2].0 =
        image::DynamicImage::ImageLuma8(image::DynamicImage::ImageRgb8(shots[2].0.clone()).to_luma8())
            .to_rgb8();
    let options = TextureOptions {
        size: Some(256),
        ..TextureOptions::default()
    };
    let texture = bake(&face, &shots, &options);
    let (error, n) = error_over(&texture, TexelSource::Seen);
    assert!(
        n > 30_000 && error < 2.0,
        "mean error {error:.2} over {n} seen texels"
    );
    // The grey photo colours only what it alone sees (the far side of the right cheek).
    assert!(
        texture.shares[2] < 0.05,
        "the grey photo's share {:?}",
        texture.shares
    );
}

#[test]
fn bad_texture_options_are_refused() {
    let face = mean_face();
    let shots = photos(&face, &[(0.0, 1.0)]);
    let photo = TexturePhoto {
        image: &shots[0].0,
        camera: shots[0].1,
        surface: None,
    };
    for options in [
        TextureOptions {
            size: Some(8),
            ..TextureOptions::default()
        },
        TextureOptions {
            sharpness: 0.0,
            ..TextureOptions::default()
        },
        TextureOptions {
            sharpness: Real::NAN,
            ..TextureOptions::default()
        },
    ] {
        assert!(matches!(
            bake_texture(&face, &[photo], &options),
            Err(FaceError::Option { .. })
        ));
    }
    assert!(matches!(
        bake_texture(&face, &[], &TextureOptions::default()),
        Err(FaceError::Option { .. })
    ));
    let empty = image::RgbImage::new(0, 0);
    let blank = TexturePhoto {
        image: &empty,
        ..photo
    };
    assert!(matches!(
        bake_texture(&face, &[blank], &TextureOptions::default()),
        Err(FaceError::Option { .. })
    ));
}

#[test]
fn the_atlas_is_inside_the_clip_region_exactly_where_the_polygon_test_says() {
    let face = mean_face();
    let shots = photos(&face, &[(0.0, 1.0)]);
    let texture = bake(
        &face,
        &shots,
        &TextureOptions {
            size: Some(200),
            ..TextureOptions::default()
        },
    );
    for (k, source) in texture.sources.iter().enumerate() {
        let (x, y) = (k % 200, k / 200);
        let p = nalgebra::Point2::new((x as Real + 0.5) / 200.0, 1.0 - (y as Real + 0.5) / 200.0);
        let inside = splineface::geometry::polygon_contains(face.clip(), p);
        assert_eq!(*source != TexelSource::Outside, inside, "texel ({x}, {y})");
    }
}

/// The default atlas's side follows the photos: photos at twice the resolution (every camera's
/// image scaled by 2) ask for twice the texels, to within the rounding to 128; the bake with the
/// default options makes an atlas of that side.
#[test]
fn the_default_atlas_follows_the_photos_resolution() {
    let face = mean_face();
    let shots = photos(&face, &[(-35.0, 1.0), (0.0, 1.0), (35.0, 1.0)]);
    let side_of = |factor: Real| {
        let photos: Vec<TexturePhoto> = shots
            .iter()
            .map(|(image, camera)| TexturePhoto {
                image,
                camera: RefinedCamera {
                    scale: camera.scale * factor,
                    offset: camera.offset * factor,
                    centre: camera.centre * factor,
                    ..*camera
                },
                surface: None,
            })
            .collect();
        automatic_atlas_side(&face, &photos).unwrap()
    };
    let (one, two) = (side_of(1.0), side_of(2.0));
    assert!(one % 128 == 0 && two % 128 == 0, "{one}, {two}");
    assert!(
        (Real::from(two) - 2.0 * Real::from(one)).abs() <= 256.0 && two > one,
        "{one} at the photos' size, {two} at twice it"
    );
    assert!((AUTOMATIC_MIN_SIDE..AUTOMATIC_MAX_SIDE).contains(&two), "{two}");
    let texture = bake(&face, &shots, &TextureOptions::default());
    assert_eq!(texture.atlas.width(), one);
    assert_eq!(texture.sources.len(), (one * one) as usize);
}
