//! The main job: `splineface demo` and `splineface reconstruct`, end to end, and their bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::common::{file_names, s, scratch, splineface};

use splineface::demo::{SceneOptions, scene, subject};
use splineface::pipeline::{PipelineOptions, reconstruct};
use splineface::reference::ReferenceFace;

const OUTPUTS: [&str; 12] = [
    "face.obj",
    "face.glb",
    "face.ply",
    "surface.json",
    "surface.step",
    "depth.exr",
    "depth.png",
    "preview.png",
    "curvature.png",
    "structure.json",
    "report.json",
    "aligned/mean-after.png",
];

#[test]
fn the_embedded_demo_subject_is_valid_and_not_the_reference() {
    let subject = subject();
    let reference = ReferenceFace::embedded();
    let moved: f64 = subject
        .structure()
        .iter()
        .zip(reference.structure())
        .map(|(a, b)| (a - b).norm())
        .sum::<f64>()
        / 40.0;
    assert!(moved > 1.0, "the subject must differ from the reference: {moved}");
}

#[test]
fn a_face_with_a_photos_expression_needs_that_photo_and_fitted_expressions() {
    use splineface::pipeline::{PipelineError, Shape};
    let inputs = points_only(4, Clone::clone);
    let with = |expression_of, shape| PipelineOptions {
        expression_of,
        shape,
        ..PipelineOptions::default()
    };
    let run = |options: &PipelineOptions| reconstruct(&inputs, ReferenceFace::embedded(), options, |_| {});
    // A photo that is not there.
    let err = run(&with(Some(4), Shape::default())).unwrap_err();
    assert!(
        matches!(err, PipelineError::ExpressionOf { photo: 4, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("there are only 4 photos"), "{err}");
    // No expressions fitted.
    let neutral = Shape::Space {
        noise: Shape::DEFAULT_NOISE,
        expressions: None,
        outline: true,
        lips: 0.0,
    };
    let err = run(&with(Some(1), neutral)).unwrap_err();
    assert!(err.to_string().contains("no expressions were fitted"), "{err}");
    // The paper's shape has none either.
    assert!(run(&with(Some(1), Shape::Deformed)).is_err());
    // With them: the identity is the neutral run's, the surface moved by photo 1's expression.
    let plain = run(&with(None, Shape::default())).unwrap();
    let posed = run(&with(Some(1), Shape::default())).unwrap();
    let (a, b) = (plain.space.as_ref().unwrap(), posed.space.as_ref().unwrap());
    assert_eq!(a.weights, b.weights);
    assert_eq!(a.expressions.len(), 4);
    let moved = posed.face.surface() != plain.face.surface();
    assert_eq!(moved, a.expressions[1].iter().any(|e| *e > 0.0));
    assert!(
        posed
            .shape
            .contains(&format!("the expression of {}", inputs[1].points.name)),
        "{}",
        posed.shape
    );
}

#[test]
fn the_library_pipeline_beats_the_mean_face() {
    let scene = scene(&SceneOptions {
        photos: 8,
        ..SceneOptions::default()
    })
    .unwrap();
    let result = reconstruct(
        &scene.inputs,
        ReferenceFace::embedded(),
        &PipelineOptions::default(),
        |_| {},
    )
    .unwrap();
    assert_eq!(result.depth.photos.len(), 8);
    assert!(result.rasl.is_some() && result.texture.is_some());
    // Every photo gave to the texture, and the mesh carries the atlas's coordinates: each
    // vertex's surface parameters.
    let texture = result.texture.as_ref().unwrap();
    assert_eq!(texture.shares.len(), 8);
    assert!(texture.shares.iter().all(|&s| s > 0.0), "{:?}", texture.shares);
    let mesh = result.output_mesh();
    assert_eq!(mesh.texture().unwrap().uvs, result.mesh.params);
    // Poses come back.
    for (fit, pose) in result.depth.photos.iter().zip(&scene.poses) {
        let [yaw, pitch, roll] = fit.pose.yaw_pitch_roll_degrees();
        assert!(
            (yaw - pose[0]).abs() < 4.0 && (pitch - pose[1]).abs() < 4.0 && (roll - pose[2]).abs() < 4.0,
            "{yaw} {pitch} {roll} vs {pose:?}"
        );
    }
    // The structure is closer to the truth than the reference's, off the contour (the demo's
    // jaw points lie on the outline each photo sees, as a landmarker's do: the truth has no
    // one place for them).
    let inner: Vec<usize> = (0..40)
        .filter(|&k| splineface::structure::POINTS[k].group != splineface::structure::Group::Contour)
        .collect();
    let rms = |a: &[nalgebra::Point3<f64>]| {
        (inner
            .iter()
            .map(|&k| (a[k] - scene.truth_structure[k]).norm_squared())
            .sum::<f64>()
            / inner.len() as f64)
            .sqrt()
    };
    let (ours, mean_face) = (
        rms(&result.depth.structure),
        rms(ReferenceFace::embedded().structure()),
    );
    assert!(
        ours < 0.6 * mean_face,
        "structure RMS {ours} vs the mean face's {mean_face}"
    );
    let files = result.files().unwrap();
    for name in OUTPUTS {
        assert!(files.iter().any(|(p, _)| p == Path::new(name)), "{name} missing");
    }
    // structure.json and report.json list their keys in sorted order, as a `serde_json` map
    // would: the files read back and written again through a map are the same bytes (the
    // command line adds the photos' records to report.json that way).
    for name in ["structure.json", "report.json"] {
        let bytes = &files.iter().find(|(p, _)| p == Path::new(name)).unwrap().1;
        let value: serde_json::Value = serde_json::from_slice(bytes).unwrap();
        assert_eq!(&serde_json::to_vec_pretty(&value).unwrap(), bytes, "{name}");
    }
    let report = result.report_file(&mesh, 0.0);
    assert!(report.rasl.is_some() && report.surface.textured);
    assert!(matches!(
        report.texture,
        Some(splineface::pipeline::files::TextureReport::Made { .. })
    ));
    assert_eq!(result.structure_file().photos.len(), 8);
    // The curvature map: the (u, v) square and its colour bar, the face region coloured.
    let png = &files
        .iter()
        .find(|(p, _)| p == Path::new("curvature.png"))
        .unwrap()
        .1;
    let map = image::load_from_memory(png).unwrap().to_rgb8();
    assert_eq!(map.height(), splineface::pipeline::files::CURVATURE_SIDE as u32);
    assert!(map.width() > map.height(), "the colour bar beside the map");
    let centre = map.get_pixel(128, 128);
    assert_ne!(centre.0, [30, 30, 30], "the face's centre is coloured");
    assert_eq!(
        map.get_pixel(1, 1).0,
        [30, 30, 30],
        "a corner of the square is outside the face"
    );
}

#[test]
fn demo_then_reconstruct_from_its_photos_and_from_its_points() {
    let dir = scratch("pipeline", "demo");
    let demo = dir.join("demo");
    let run = splineface(&["demo", "--out", &s(&demo), "--photos", "6"]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        stdout.contains("structure SSIM") && stdout.contains("mean face"),
        "{stdout}"
    );
    for name in OUTPUTS {
        assert!(demo.join("reconstruction").join(name).is_file(), "{name}");
    }
    // The page, and an overlay per photo (the demo's points are given, not detected: no
    // landmarks/).
    assert!(demo.join("report.html").is_file());
    for k in 1..=6 {
        assert!(
            demo.join(format!("reconstruction/overlays/photo{k:02}.jpg"))
                .is_file()
        );
    }
    assert!(!demo.join("reconstruction/landmarks").exists());
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(demo.join("compare/stats.json")).unwrap()).unwrap();
    // Scored as every accuracy claim is: the truth's inner face to the surface (the depth error
    // |Δz| after a landmark alignment does not show the shape; README).
    let ours = stats["inner_face"]["distance"]["mean"].as_f64().unwrap();
    let baseline = stats["baseline_mean_face"]["inner_face"]["distance"]["mean"]
        .as_f64()
        .unwrap();
    assert!(
        ours < 0.9 * baseline,
        "{ours} mm vs the mean face's {baseline} mm"
    );

    // reconstruct from the demo's photos and landmark files.
    let photos = demo.join("photos");
    let out = dir.join("from-photos");
    let run = splineface(&[
        "reconstruct",
        "--photos",
        &s(&photos),
        "--landmarks",
        &s(&photos),
        "--out",
        &s(&out),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    for name in OUTPUTS
        .iter()
        .chain(&["face.mtl", "face.png", "report.html", "overlays/photo06.jpg"])
    {
        assert!(out.join(name).is_file(), "{name}");
    }
    let structure: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("structure.json")).unwrap()).unwrap();
    assert_eq!(structure["units"], "mm");
    assert_eq!(structure["photos"].as_array().unwrap().len(), 6);
    let right = structure["eye_centres"]["right"][0].as_f64().unwrap();
    assert!((right + 31.5).abs() < 1e-9, "eye centres at ±31.5 mm: {right}");
    let (document, _, images) = gltf::import(out.join("face.glb")).unwrap();
    assert_eq!(document.meshes().count(), 1);
    assert_eq!(images.len(), 1);
    // The atlas's side is the photos' (a multiple of 128, 256 to 2048), as the summary and
    // report.json say.
    let side = images[0].width;
    assert!(side % 128 == 0 && (256..=2048).contains(&side), "{side}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["texture"]["size"], side);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains(&format!(", textured ({side} × {side} atlas)")),
        "{stdout}"
    );

    // Points only, in canonical units.
    let out = dir.join("points-only");
    let run = splineface(&[
        "reconstruct",
        "--landmarks",
        &s(&photos),
        "--out",
        &s(&out),
        "--units",
        "canonical",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        out.join("face.obj").is_file()
            && !out.join("face.png").exists()
            && !out.join("aligned").exists()
            && !out.join("overlays").exists()
            && out.join("report.html").is_file()
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["frontal_method"], "Procrustes");
    // Every photo's expression is fitted and listed; the demo subject smiles, so some photo's
    // weights are not all zero.
    let neutral: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("structure.json")).unwrap()).unwrap();
    let expressions = neutral["expressions"].as_array().unwrap();
    assert_eq!(expressions.len(), 6, "{expressions:?}");
    assert!(
        expressions
            .iter()
            .any(|e| !e["weights"].as_object().unwrap().is_empty()),
        "{expressions:?}"
    );
    // The face with one photo's expression: the neutral face moved by it (the same identity).
    let posed = dir.join("posed");
    let run = splineface(&[
        "reconstruct",
        "--landmarks",
        &s(&photos),
        "--out",
        &s(&posed),
        "--units",
        "canonical",
        "--expression-of",
        "photo01",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(posed.join("report.json")).unwrap()).unwrap();
    assert!(
        report["surface"]["shape"]
            .as_str()
            .unwrap()
            .contains("with the expression of photo01"),
        "{report}"
    );
    let structure: serde_json::Value =
        serde_json::from_slice(&std::fs::read(posed.join("structure.json")).unwrap()).unwrap();
    let smiling = expressions.iter().find(|e| e["name"] == "photo01").unwrap();
    let moved =
        std::fs::read(posed.join("face.obj")).unwrap() != std::fs::read(out.join("face.obj")).unwrap();
    assert_eq!(moved, !smiling["weights"].as_object().unwrap().is_empty());
    assert_eq!(structure["space_weights"], neutral["space_weights"]);

    // A corrupt photo is skipped and reported; the rest still make a face.
    let mixed = dir.join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    for entry in std::fs::read_dir(&photos).unwrap() {
        let p = entry.unwrap().path();
        std::fs::copy(&p, mixed.join(p.file_name().unwrap())).unwrap();
    }
    std::fs::write(mixed.join("photo03.png"), b"not a png").unwrap();
    // A photo whose landmark file is damaged, and one without a landmark file.
    std::fs::write(mixed.join("photo04.pts"), "version: 1\nn_points: 68\n{\n1 2\n").unwrap();
    std::fs::remove_file(mixed.join("photo05.pts")).unwrap();
    // The same photo under another extension: its name is taken by the first in order.
    std::fs::copy(mixed.join("photo02.png"), mixed.join("photo02.bmp")).unwrap();
    let out = dir.join("mixed-out");
    let run = splineface(&[
        "reconstruct",
        "--photos",
        &s(&mixed),
        "--landmarks",
        &s(&mixed),
        "--out",
        &s(&out),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(String::from_utf8_lossy(&run.stderr).contains("photo03.png"));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["photos_used"].as_array().unwrap().len(), 3, "{report}");
    // Every stage is timed, the page's own last (the page, made from report.json, cannot show
    // it); the terminal adds the writing.
    let stages: Vec<&str> = report["timings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages[stages.len() - 2..],
        ["overlays (drawn beside the texture)", "report page"],
        "{stages:?}"
    );
    assert!(String::from_utf8_lossy(&run.stdout).contains("ms  writing the files"));
    let skipped = report["photos_skipped"].to_string();
    for reason in [
        "photo03.png: cannot read the image",
        "photo04.png: its landmarks: ",
        "photo04.pts: the file ends after 1 of 68 points",
        "photo05.png: no landmark file photo05.pts or photo05.json",
        "photo02.png: ",
        "photo02.bmp has the same name `photo02`",
    ] {
        assert!(skipped.contains(reason), "{reason}: {skipped}");
    }
    // Asking for more photos than are usable stops the run, listing each skipped photo.
    let strict = splineface(&[
        "reconstruct",
        "--photos",
        &s(&mixed),
        "--landmarks",
        &s(&mixed),
        "--out",
        &s(&dir.join("strict")),
        "--min-photos",
        "4",
    ]);
    let message = String::from_utf8_lossy(&strict.stderr);
    assert_eq!(strict.status.code(), Some(1), "{message}");
    assert!(
        message.contains("3 usable photos, at least 4 needed (--min-photos)"),
        "{message}"
    );
    assert!(
        message.contains("skipped") && message.contains("photo05.png"),
        "{message}"
    );
    assert!(!dir.join("strict").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn reconstruct_refuses_bad_input() {
    let dir = scratch("pipeline", "bad");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let scene = scene(&SceneOptions {
        photos: 3,
        ..SceneOptions::default()
    })
    .unwrap();
    for (p, bytes) in scene.files().unwrap() {
        std::fs::write(photos.join(p), bytes).unwrap();
    }
    // A landmark file with the wrong count.
    let wrong = dir.join("wrong");
    std::fs::create_dir_all(&wrong).unwrap();
    std::fs::write(
        wrong.join("a.pts"),
        "version: 1\nn_points: 3\n{\n1 2\n3 4\n5 6\n}\n",
    )
    .unwrap();
    let file_in_the_way = dir.join("file");
    std::fs::write(&file_in_the_way, "x").unwrap();
    let out = s(&dir.join("out"));
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["reconstruct".into(), "--out".into(), out.clone()],
            "nothing to reconstruct",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&dir.join("missing")),
                "--out".into(),
                out.clone(),
            ],
            "missing",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&wrong),
                "--out".into(),
                out.clone(),
            ],
            "a.pts",
        ),
        (
            vec![
                "reconstruct".into(),
                "--photos".into(),
                s(&photos),
                "--out".into(),
                out.clone(),
            ],
            "--landmarks",
        ),
        (
            vec![
                "reconstruct".into(),
                s(&dir.join("nope.jpg")),
                "--landmarks".into(),
                s(&photos),
                "--out".into(),
                out.clone(),
            ],
            "nope.jpg",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&photos),
                "--out".into(),
                s(&file_in_the_way),
            ],
            "not a directory",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&photos),
                "--out".into(),
                out.clone(),
                "--units".into(),
                "inches".into(),
            ],
            "--units",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&photos),
                "--out".into(),
                out.clone(),
                "--spacing".into(),
                "0".into(),
            ],
            "--spacing",
        ),
        (
            vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&photos),
                "--reference".into(),
                s(&file_in_the_way),
                "--out".into(),
                out.clone(),
            ],
            "reference",
        ),
        (
            vec![
                "demo".into(),
                "--out".into(),
                out.clone(),
                "--photos".into(),
                "0".into(),
            ],
            "photos",
        ),
    ];
    for (args, message) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let run = splineface(&args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains(message), "{args:?}: {stderr}");
    }
    assert!(!dir.join("out").exists(), "nothing may be written on failure");
    // An unwritable output directory: nothing is left behind in it.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let locked = dir.join("locked");
        std::fs::create_dir_all(&locked).unwrap();
        std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o555)).unwrap();
        let target = locked.join("out");
        let run = splineface(&["reconstruct", "--landmarks", &s(&photos), "--out", &s(&target)]);
        std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o755)).unwrap();
        // Root may write anyway; either it fails cleanly or it succeeds whole.
        if !run.status.success() {
            assert_eq!(run.status.code(), Some(1));
            assert!(!target.exists() || std::fs::read_dir(&target).unwrap().next().is_none());
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Photos without landmark files are detected and landmarked with dlib's model. In a batch
/// built from the fixture, a photo with no face, one with two faces of one size, a group photo
/// and a corrupt file are skipped and reported; a photo with a small second face uses the
/// largest and says so; the face comes from the three usable photos.
#[test]
#[ignore = "needs ../shared (dlib's model and photos)"]
fn reconstruct_detects_and_landmarks_faces() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let dir = scratch("pipeline", "detect");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let faces = shared.join("data/dlib-faces");
    for name in ["bald_guys.jpg", "dogs.jpg"] {
        std::fs::copy(faces.join(name), photos.join(name)).unwrap();
    }
    let tom_path = faces.join("Tom_Cruise_avp_2014_4.jpg");
    let tom = image::open(&tom_path).unwrap().to_rgb8();
    let (w, h) = tom.dimensions();
    tom.save(photos.join("tom.png")).unwrap();
    image::imageops::flip_horizontal(&tom)
        .save(photos.join("tom-mirrored.png"))
        .unwrap();
    // A copy at a third of the size in a corner: a clearly smaller second face.
    let mut with_small = tom.clone();
    let small = image::imageops::resize(&tom, w / 3, h / 3, image::imageops::FilterType::Triangle);
    image::imageops::replace(&mut with_small, &small, 0, 0);
    with_small.save(photos.join("tom-with-a-small-face.png")).unwrap();
    // Two copies side by side: two faces of one size.
    let mut twins = image::RgbImage::new(2 * w, h);
    image::imageops::replace(&mut twins, &tom, 0, 0);
    image::imageops::replace(&mut twins, &tom, i64::from(w), 0);
    twins.save(photos.join("two-toms.png")).unwrap();
    // A download cut short.
    let bytes = std::fs::read(&tom_path).unwrap();
    std::fs::write(photos.join("truncated.jpg"), &bytes[..200]).unwrap();
    let out = dir.join("out");
    let model = shared.join("models/shape_predictor_68_face_landmarks.dat");
    let run = splineface(&[
        "reconstruct",
        "--photos",
        &s(&photos),
        "--landmark-model",
        &s(&model),
        "--out",
        &s(&out),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let used: Vec<&str> = report["photos_used"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap())
        .collect();
    // In name order ("-" sorts before ".").
    assert_eq!(used, ["tom-mirrored", "tom-with-a-small-face", "tom"], "{report}");
    let skipped: Vec<&str> = report["photos_skipped"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap())
        .collect();
    assert_eq!(skipped.len(), 4, "{report}");
    for (photo, reason) in [
        (
            "bald_guys.jpg",
            "faces found and the two largest are of about one size",
        ),
        ("dogs.jpg", "no face found"),
        ("truncated.jpg", "truncated.jpg"),
        (
            "two-toms.png",
            "2 faces found and the two largest are of about one size",
        ),
    ] {
        assert!(
            skipped.iter().any(|s| s.contains(photo) && s.contains(reason)),
            "{photo}: {skipped:?}"
        );
        assert!(
            stderr.contains(&format!("skipped {}", photos.join(photo).display())),
            "{stderr}"
        );
    }
    let warnings = report["warnings"].to_string();
    assert!(
        warnings.contains("tom-with-a-small-face.png: 2 faces found; the largest is used"),
        "{warnings}"
    );
    assert!(out.join("face.glb").is_file());
    // An overlay for every photo that decodes, used or skipped; the truncated file has none
    // (its reason is in the report and on the page).
    assert_eq!(
        file_names(&out.join("overlays")),
        [
            "bald_guys.jpg",
            "dogs.jpg",
            "tom-mirrored.jpg",
            "tom-with-a-small-face.jpg",
            "tom.jpg",
            "two-toms.jpg"
        ]
    );
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        page.contains("no face found") && page.contains("truncated"),
        "the page names the skipped photos"
    );
    // The detected landmarks as .pts, read back by --landmarks: the same points, so the same
    // face.
    assert_eq!(
        file_names(&out.join("landmarks")),
        ["tom-mirrored.pts", "tom-with-a-small-face.pts", "tom.pts"]
    );
    for name in &used {
        let points =
            splineface::landmarks::read_pts(&out.join("landmarks").join(format!("{name}.pts"))).unwrap();
        assert_eq!(points.len(), 68);
    }
    let again = dir.join("again");
    let run = splineface(&[
        "reconstruct",
        "--photos",
        &s(&photos),
        "--landmarks",
        &s(&out.join("landmarks")),
        "--out",
        &s(&again),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let structure = |dir: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(dir.join("structure.json")).unwrap()).unwrap()
    };
    assert_eq!(structure(&out)["points"], structure(&again)["points"]);
    // `splineface landmarks`: the same points, landmark JSON, and the same overlays' names.
    let alone = dir.join("landmarks-alone");
    let run = splineface(&[
        "landmarks",
        "--photos",
        &s(&photos),
        "--landmark-model",
        &s(&model),
        "--json",
        "--out",
        &s(&alone),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("dogs.jpg: skipped: no face found"), "{stdout}");
    for name in &used {
        assert_eq!(
            std::fs::read(alone.join(format!("{name}.pts"))).unwrap(),
            std::fs::read(out.join("landmarks").join(format!("{name}.pts"))).unwrap()
        );
        let json = splineface::landmarks::read_landmarks_json(&alone.join(format!("{name}.json"))).unwrap();
        assert_eq!(json.scheme, splineface::landmarks::Scheme::Ibug68);
    }
    assert_eq!(
        file_names(&alone.join("overlays")),
        file_names(&out.join("overlays"))
    );
    // With the bar above the usable photos, the run stops and lists every skipped photo.
    let strict = splineface(&[
        "reconstruct",
        "--photos",
        &s(&photos),
        "--landmark-model",
        &s(&model),
        "--min-photos",
        "4",
        "--out",
        &s(&dir.join("strict")),
    ]);
    let message = String::from_utf8_lossy(&strict.stderr);
    assert_eq!(strict.status.code(), Some(1), "{message}");
    assert!(
        message.contains("3 usable photos, at least 4 needed"),
        "{message}"
    );
    assert!(message.contains("dogs.jpg: no face found"), "{message}");
    assert!(!dir.join("strict").exists());
    // A model file that is not one.
    let bad = splineface(&[
        "reconstruct",
        "--photos",
        &s(&photos),
        "--landmark-model",
        &s(&photos.join("dogs.jpg")),
        "--out",
        &s(&dir.join("bad")),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("dogs.jpg"));
    assert!(!dir.join("bad").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The evaluation harness end to end, in its quick setting (about a minute once built).
#[test]
#[ignore = "needs ../shared (ICT-FaceKit) and builds the eval tool in release"]
fn the_evaluation_harness_runs() {
    let dir = scratch("pipeline", "eval");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned());
    let run = Command::new(cargo)
        .args([
            "run",
            "--quiet",
            "--release",
            "--example",
            "eval",
            "--",
            "--quick",
            "--out",
            &s(&dir),
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let page = std::fs::read_to_string(dir.join("evaluation.md")).unwrap();
    for heading in ["## Table 1", "## Fig. 8(3)", "## Table 2", "### Subject 2"] {
        assert!(page.contains(heading), "{heading} missing");
    }
    assert!(page.contains("cargo run --release --example eval -- --quick"));
    let plot = image::open(dir.join("error-vs-photos.png")).unwrap();
    assert_eq!((plot.width(), plot.height()), (640, 400));
    // The default beats the mean face on the inner-face error (the table's first column).
    let mean_of = |name: &str| -> f64 {
        let line = page
            .lines()
            .find(|l| l.starts_with(&format!("| {name}")))
            .unwrap();
        line.split('|')
            .nth(2)
            .unwrap()
            .split('±')
            .next()
            .unwrap()
            .trim()
            .parse()
            .unwrap()
    };
    assert!(mean_of("**default**") < mean_of("mean face"), "{page}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The same inputs give byte-identical outputs across runs and thread counts (`report.json`
/// differs only in its timings).
#[test]
fn outputs_are_repeatable_across_runs_and_thread_counts() {
    let dir = scratch("pipeline", "repeat");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let scene = scene(&SceneOptions {
        photos: 5,
        ..SceneOptions::default()
    })
    .unwrap();
    for (p, bytes) in scene.files().unwrap() {
        std::fs::write(photos.join(p), bytes).unwrap();
    }
    let run = |name: &str, threads: &str| -> PathBuf {
        let out = dir.join(name);
        let result = Command::new(env!("CARGO_BIN_EXE_splineface"))
            .args([
                "reconstruct",
                "--photos",
                &s(&photos),
                "--landmarks",
                &s(&photos),
                "--out",
                &s(&out),
            ])
            .env("RAYON_NUM_THREADS", threads)
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "{}",
            String::from_utf8_lossy(&result.stderr)
        );
        out
    };
    let runs = [run("a", "1"), run("b", "2"), run("c", "2"), run("d", "3")];
    let mut files: Vec<PathBuf> = OUTPUTS.iter().map(PathBuf::from).collect();
    files.extend(
        [
            "face.png",
            "face.mtl",
            "texture-confidence.png",
            "turntable.png",
            "aligned/sparse.png",
            "aligned/low-rank.png",
        ]
        .map(PathBuf::from),
    );
    for file in &files {
        let first = std::fs::read(runs[0].join(file)).unwrap();
        for other in &runs[1..] {
            let bytes = std::fs::read(other.join(file)).unwrap();
            if file == Path::new("report.json") {
                let strip = |b: &[u8]| {
                    let mut v: serde_json::Value = serde_json::from_slice(b).unwrap();
                    v["timings"] = serde_json::Value::Null;
                    v["photo_timings"] = serde_json::Value::Null;
                    v["rasl"]["seconds"] = serde_json::Value::Null;
                    v
                };
                assert_eq!(strip(&first), strip(&bytes), "report.json beyond its timings");
            } else {
                assert!(
                    first == bytes,
                    "{} differs between {} and {}",
                    file.display(),
                    runs[0].display(),
                    other.display()
                );
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Every file under `dir` (temporaries aside), by relative path; `report.json` without its
/// timings, which differ from run to run.
fn outputs_in(dir: &Path) -> (std::collections::BTreeMap<PathBuf, Vec<u8>>, usize) {
    let mut files = std::collections::BTreeMap::new();
    let mut temporaries = 0;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if path.is_dir() {
                stack.push(path);
            } else if name.starts_with('.') && name.ends_with(".tmp") {
                temporaries += 1;
            } else {
                let mut bytes = std::fs::read(&path).unwrap();
                if name == "report.json" {
                    let mut v: serde_json::Value = serde_json::from_slice(&bytes)
                        .unwrap_or_else(|e| panic!("{}: not whole JSON: {e}", path.display()));
                    v["timings"] = serde_json::Value::Null;
                    v["photo_timings"] = serde_json::Value::Null;
                    v["rasl"]["seconds"] = serde_json::Value::Null;
                    bytes = serde_json::to_vec(&v).unwrap();
                } else if name == "report.html" {
                    // The page's timings table varies from run to run; the rest must not.
                    let text = String::from_utf8(bytes).unwrap();
                    let start = text.find("<h3>Timings</h3>").unwrap_or(text.len());
                    let end = text[start..].find("</table>").map_or(text.len(), |e| start + e);
                    bytes = format!("{}{}", &text[..start], &text[end..]).into_bytes();
                }
                files.insert(path.strip_prefix(dir).unwrap().to_path_buf(), bytes);
            }
        }
    }
    (files, temporaries)
}

/// Runs killed (SIGKILL) at times spread over a whole run, into a folder holding a previous
/// run's outputs: afterwards every file there is byte for byte either the previous version or
/// the new one, never cut short; and the next run completes and clears the temporaries the
/// killed runs left.
#[test]
fn a_killed_run_leaves_every_output_whole() {
    let dir = scratch("pipeline", "killed");
    // Two batches of photos: the previous outputs come from one, the new from the other.
    for (name, seed) in [("photos-old", 1), ("photos", 2)] {
        let photos = dir.join(name);
        std::fs::create_dir_all(&photos).unwrap();
        let scene = scene(&SceneOptions {
            photos: 6,
            seed,
            ..SceneOptions::default()
        })
        .unwrap();
        for (p, bytes) in scene.files().unwrap() {
            std::fs::write(photos.join(p), bytes).unwrap();
        }
    }
    let command = |out: &Path, photos: &str| {
        let photos = dir.join(photos);
        let mut command = Command::new(env!("CARGO_BIN_EXE_splineface"));
        command
            .args(["reconstruct", "--photos", &s(&photos), "--landmarks", &s(&photos)])
            .args(["--out", &s(out)])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
        command
    };
    // The previous outputs and the new ones, each from a whole run.
    let (old_dir, new_dir) = (dir.join("old"), dir.join("new"));
    assert!(command(&old_dir, "photos-old").status().unwrap().success());
    let start = std::time::Instant::now();
    assert!(command(&new_dir, "photos").status().unwrap().success());
    let whole_run = start.elapsed();
    let (old, _) = outputs_in(&old_dir);
    let (new, _) = outputs_in(&new_dir);
    assert_eq!(old.keys().collect::<Vec<_>>(), new.keys().collect::<Vec<_>>());

    let target = dir.join("target");
    let (mut all_old, mut mixed, mut all_new, mut temporaries_seen) = (0, 0, 0, 0);
    // Kill times: at once, then from 55% to 115% of a whole run, where the writing happens.
    for k in 0..21u32 {
        let _ = std::fs::remove_dir_all(&target);
        for name in old.keys() {
            std::fs::create_dir_all(target.join(name).parent().unwrap()).unwrap();
            std::fs::copy(old_dir.join(name), target.join(name)).unwrap();
        }
        let mut child = command(&target, "photos").spawn().unwrap();
        if k > 0 {
            std::thread::sleep(whole_run.mul_f64(0.52 + 0.03 * f64::from(k)));
        }
        let _ = child.kill();
        child.wait().unwrap();
        let (now, temporaries) = outputs_in(&target);
        temporaries_seen += temporaries;
        assert_eq!(now.keys().collect::<Vec<_>>(), old.keys().collect::<Vec<_>>());
        let (mut olds, mut news) = (0, 0);
        for (name, bytes) in &now {
            if old[name] == new[name] {
                assert!(*bytes == old[name], "kill {k}: {} is damaged", name.display());
            } else if *bytes == old[name] {
                olds += 1;
            } else if *bytes == new[name] {
                news += 1;
            } else {
                panic!("kill {k}: {} is neither the old nor the new file", name.display());
            }
        }
        match (olds, news) {
            (_, 0) => all_old += 1,
            (0, _) => all_new += 1,
            _ => mixed += 1,
        }
    }
    // The first kill comes before any output could be written.
    assert!(all_old > 0, "{all_old} old, {mixed} mixed, {all_new} new");
    assert!(command(&target, "photos").status().unwrap().success());
    let (after, temporaries) = outputs_in(&target);
    assert_eq!(temporaries, 0, "the temporaries of killed runs are cleared");
    assert!(after == new, "a completed run writes the new outputs");
    eprintln!(
        "kills: {all_old} left the old outputs, {mixed} a mix, {all_new} the new; {temporaries_seen} temporaries seen; a run takes {whole_run:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `splineface landmarks` on photos an overlay is hard to draw on: a greyscale photo is
/// landmarked and drawn in grey; a thumbnail too small for a face gets an overlay (scaled up)
/// saying none was found; a file that is not an image gets its reason on the terminal.
#[test]
#[ignore = "needs ../shared (dlib's model and photos)"]
fn landmarks_draws_every_photo_it_can_decode_and_names_the_rest() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let dir = scratch("pipeline", "landmarks-odd");
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let tom = image::open(shared.join("data/dlib-faces/Tom_Cruise_avp_2014_4.jpg")).unwrap();
    tom.to_luma8().save(photos.join("grey.png")).unwrap();
    image::imageops::resize(&tom.to_rgb8(), 24, 18, image::imageops::FilterType::Triangle)
        .save(photos.join("thumbnail.png"))
        .unwrap();
    std::fs::write(photos.join("not-an-image.jpg"), b"hello").unwrap();
    let out = dir.join("out");
    let run = splineface(&[
        "landmarks",
        "--photos",
        &s(&photos),
        "--landmark-model",
        &s(&shared.join("models/shape_predictor_68_face_landmarks.dat")),
        "--out",
        &s(&out),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("grey.png: 68 points"), "{stdout}");
    assert!(
        stdout.contains("thumbnail.png: skipped: no face found"),
        "{stdout}"
    );
    assert!(stdout.contains("not-an-image.jpg: skipped:"), "{stdout}");
    assert_eq!(
        splineface::landmarks::read_pts(&out.join("grey.pts"))
            .unwrap()
            .len(),
        68
    );
    assert!(!out.join("thumbnail.pts").exists() && !out.join("not-an-image.pts").exists());
    let grey = image::open(out.join("overlays/grey.jpg")).unwrap().to_rgb8();
    // The photo part stays grey; the marks are green and yellow.
    let (w, h) = grey.dimensions();
    let middle = grey.get_pixel(w / 8, h - 4).0;
    assert!(middle[0] == middle[1] && middle[1] == middle[2], "{middle:?}");
    let thumbnail = image::open(out.join("overlays/thumbnail.jpg")).unwrap();
    assert_eq!(thumbnail.width(), splineface::report::MIN_SIDE);
    assert!(!out.join("overlays/not-an-image.jpg").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_jaw_points_are_fitted_on_the_faces_outline() {
    use splineface::face::OUTLINE_POINTS;
    use splineface::pipeline::Shape;
    // The demo's jaw points lie on the subject's outline as each photo sees it.
    let scene = scene(&SceneOptions {
        photos: 8,
        ..SceneOptions::default()
    })
    .unwrap();
    let run = |outline| {
        let options = PipelineOptions {
            shape: Shape::Space {
                noise: Shape::DEFAULT_NOISE,
                expressions: Some(splineface::face::ExpressionPrior::DEFAULT),
                outline,
                lips: 0.0,
            },
            refine: None,
            ..PipelineOptions::default()
        };
        reconstruct(&scene.inputs, ReferenceFace::embedded(), &options, |_| {}).unwrap()
    };
    // How far the fitted jaw points lie from the photos', pixels (RMS over every photo).
    let jaw = |result: &splineface::pipeline::Reconstruction| {
        let mut squares = Vec::new();
        for (fit, input) in result.photo_fits.iter().zip(&scene.inputs) {
            assert_eq!(fit.name, input.points.name);
            for &j in &OUTLINE_POINTS {
                squares.push((fit.points[j] - input.points.points[j]).norm_squared());
            }
        }
        (squares.iter().sum::<f64>() / squares.len() as f64).sqrt()
    };
    let (with, without) = (run(true), run(false));
    // The report says how the jaw's points were measured.
    let shape = |result: &splineface::pipeline::Reconstruction| {
        result.report_file(&result.output_mesh(), 0.0).surface.shape
    };
    assert!(shape(&with).contains("outline"), "{}", shape(&with));
    assert!(!shape(&without).contains("outline"), "{}", shape(&without));
    // Measured: 3.3 against 7.8 px.
    assert!(
        jaw(&with) < 0.6 * jaw(&without),
        "{} against {} px",
        jaw(&with),
        jaw(&without)
    );
}

#[test]
fn inner_lips_parted_in_every_photo_open_the_fitted_jaw() {
    use splineface::align::{FIRST_INNER_LIP, INNER_LIP_COUNT};
    use splineface::pipeline::Shape;
    // Each photo's inner lips: on the line between its mouth corners (structure points 36 and
    // 32, iBUG 48 and 54), the upper ones at the corners' height and the lower ones a fifth of
    // the mouth's width below (image y down): a mouth held open.
    let inputs = points_only(4, |photo| {
        let p = &photo.points;
        let (right, left) = (p[36], p[32]);
        let width = (left - right).norm();
        let inner_lips = (0..INNER_LIP_COUNT)
            .map(|k| {
                let ibug = FIRST_INNER_LIP + k;
                // 60..64 run right to left along the upper lip, 65..67 back along the lower.
                let (t, lower) = match ibug {
                    60..=64 => ((ibug - 60) as f64 / 4.0, false),
                    _ => ((68 - ibug) as f64 / 4.0, true),
                };
                let on_line = right + (left - right) * t;
                let drop = if lower { 0.2 * width } else { 0.0 };
                nalgebra::Point2::new(on_line.x, on_line.y + drop)
            })
            .collect();
        splineface::align::PhotoPoints {
            inner_lips,
            ..photo.clone()
        }
    });
    let run = |lips| {
        let options = PipelineOptions {
            shape: Shape::Space {
                noise: Shape::DEFAULT_NOISE,
                expressions: Some(splineface::face::ExpressionPrior::DEFAULT),
                outline: true,
                lips,
            },
            ..PipelineOptions::default()
        };
        reconstruct(&inputs, ReferenceFace::embedded(), &options, |_| {}).unwrap()
    };
    let jaw = |result: &splineface::pipeline::Reconstruction| {
        let fit = result.space.as_ref().expect("the default shape fits the space");
        let l = fit.expression_names.iter().position(|n| n == "jawOpen").unwrap();
        fit.expressions.iter().map(|e| e[l]).sum::<f64>() / fit.expressions.len() as f64
    };
    let (with, without) = (run(splineface::face::LIP_WEIGHT), run(0.0));
    assert!(
        jaw(&with) > jaw(&without) + 0.05,
        "jaw open {} with the lips, {} without",
        jaw(&with),
        jaw(&without)
    );
    assert!(with.shape.contains("inner lips of 4 photos"), "{}", with.shape);
    assert!(!without.shape.contains("inner lips"), "{}", without.shape);
}

/// The demo scene's first `photos` photos as points only (fast, and enough for the shape), each
/// photo's points made by `points` from the scene's.
fn points_only(
    photos: usize,
    points: impl Fn(&splineface::align::PhotoPoints) -> splineface::align::PhotoPoints,
) -> Vec<splineface::pipeline::Input> {
    let scene = scene(&SceneOptions {
        photos,
        ..SceneOptions::default()
    })
    .unwrap();
    scene
        .inputs
        .iter()
        .map(|i| splineface::pipeline::Input {
            points: points(&i.points),
            image: None,
        })
        .collect()
}

/// A photo RASL leaves out (here: a point off the image) is left out of the face too: the face
/// and its weights are the ones the photos RASL kept give on their own.
#[test]
fn a_photo_rasl_leaves_out_is_left_out_of_the_face_too() {
    let scene = scene(&SceneOptions {
        photos: 4,
        ..SceneOptions::default()
    })
    .unwrap();
    let mut inputs = scene.inputs.clone();
    let width = inputs[2].image.as_ref().unwrap().colour.width() as f64;
    // A brow point just off the right edge: fine for the fit, refused by RASL.
    let brow = &mut inputs[2].points.points[10];
    brow.x = width + 2.0;
    let options = PipelineOptions::default();
    let result = reconstruct(&inputs, ReferenceFace::embedded(), &options, |_| {}).unwrap();
    let name = &inputs[2].points.name;
    assert!(
        result
            .dropped
            .iter()
            .any(|d| &d.name == name && d.reason.contains("outside")),
        "{:?}",
        result.dropped
    );
    let kept: Vec<_> = [0, 1, 3].map(|k| inputs[k].clone()).into();
    let alone = reconstruct(&kept, ReferenceFace::embedded(), &options, |_| {}).unwrap();
    assert_eq!(result.depth.photos.len(), 3);
    assert_eq!(
        result.face.surface().control_points(),
        alone.face.surface().control_points()
    );
    assert_eq!(
        result.space.as_ref().unwrap().weights,
        alone.space.as_ref().unwrap().weights
    );
}
