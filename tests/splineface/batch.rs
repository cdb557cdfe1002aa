//! `splineface batch`: subjects in folders, their outputs as `reconstruct` writes them, the
//! summary, resuming, failed subjects and bad roots.

use super::common::{s, scratch, splineface};
use std::path::Path;

use splineface::demo::{SceneOptions, scene};

/// A subject folder: `photos` rendered photos of the demo subject with their landmark files.
fn subject_folder(folder: &Path, photos: usize, seed: u64) {
    let scene = scene(&SceneOptions {
        photos,
        seed,
        size: (240, 288),
        ..SceneOptions::default()
    })
    .unwrap();
    splineface::io::write_into(folder, &scene.files().unwrap()).unwrap();
}

/// The summary's rows as `subject → (status, message)`.
fn summary(out: &Path) -> Vec<(String, String, String)> {
    let text = std::fs::read_to_string(out.join("summary.jsonl")).unwrap();
    text.lines()
        .map(|line| {
            let row: serde_json::Value = serde_json::from_str(line).unwrap();
            (
                row["subject"].as_str().unwrap().to_owned(),
                row["status"].as_str().unwrap().to_owned(),
                row["message"].as_str().unwrap().to_owned(),
            )
        })
        .collect()
}

#[test]
fn a_batch_reconstructs_each_subject_resumes_and_reports_failures() {
    let dir = scratch("batch", "run");
    let root = dir.join("subjects");
    subject_folder(&root.join("alice"), 4, 1);
    subject_folder(&root.join("bob"), 3, 2);
    // Photos with no landmark files and no model; an empty folder.
    std::fs::create_dir_all(root.join("carol")).unwrap();
    std::fs::copy(root.join("alice/photo01.png"), root.join("carol/photo01.png")).unwrap();
    std::fs::create_dir_all(root.join("empty")).unwrap();
    let out = dir.join("out");
    let flags = ["--no-refine", "--texture-size", "64"];
    let run = |extra: &[&str]| {
        let mut args = vec!["batch".to_owned(), s(&root), "--out".to_owned(), s(&out)];
        args.extend(flags.iter().chain(extra).map(|a| a.to_string()));
        splineface(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };

    let first = run(&[]);
    // Two subjects failed: exit status 1, every subject still in the summary.
    assert_eq!(
        first.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let stderr = String::from_utf8_lossy(&first.stderr);
    assert!(stderr.contains("2 of 4 subjects failed"), "{stderr}");
    let rows = summary(&out);
    let status: Vec<(&str, &str)> = rows.iter().map(|(s, st, _)| (s.as_str(), st.as_str())).collect();
    assert_eq!(
        status,
        [
            ("alice", "done"),
            ("bob", "done"),
            ("carol", "failed"),
            ("empty", "failed")
        ]
    );
    assert!(rows[2].2.contains("no landmark model"), "{}", rows[2].2);
    assert!(rows[3].2.contains("no photos or landmark files"), "{}", rows[3].2);
    let csv = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    assert_eq!(
        csv.lines().next().unwrap(),
        splineface::batch::SUMMARY_COLUMNS.join(",")
    );
    assert!(csv.contains("\nalice,done,4,4,0,0,"), "{csv}");
    assert!(!out.join("carol").exists(), "a failed subject leaves no outputs");

    // A subject's outputs are what `reconstruct` writes for its folder (timings aside).
    let single = dir.join("single");
    let alone = splineface(&[
        "reconstruct",
        "--photos",
        &s(&root.join("alice")),
        "--landmarks",
        &s(&root.join("alice")),
        "--out",
        &s(&single),
        "--no-refine",
        "--texture-size",
        "64",
    ]);
    assert!(
        alone.status.success(),
        "{}",
        String::from_utf8_lossy(&alone.stderr)
    );
    for file in [
        "structure.json",
        "face.obj",
        "surface.json",
        "face.png",
        "overlays/photo01.jpg",
    ] {
        assert_eq!(
            std::fs::read(out.join("alice").join(file)).unwrap(),
            std::fs::read(single.join(file)).unwrap(),
            "{file}"
        );
    }

    // Again: nothing changed, nothing redone; the rows carry the first run's figures.
    let stamp = std::fs::metadata(out.join("alice/face.obj"))
        .unwrap()
        .modified()
        .unwrap();
    let _ = run(&[]);
    let rows = summary(&out);
    assert_eq!(
        (rows[0].1.as_str(), rows[1].1.as_str()),
        ("unchanged", "unchanged")
    );
    assert_eq!(
        std::fs::metadata(out.join("alice/face.obj"))
            .unwrap()
            .modified()
            .unwrap(),
        stamp
    );
    // A changed landmark file redoes its subject only; so does a changed option for all.
    let pts = root.join("bob/photo01.pts");
    let text = std::fs::read_to_string(&pts).unwrap();
    std::fs::write(&pts, format!("{text}\n")).unwrap();
    let _ = run(&[]);
    let rows = summary(&out);
    assert_eq!((rows[0].1.as_str(), rows[1].1.as_str()), ("unchanged", "done"));
    let _ = run(&["--units", "canonical"]);
    let rows = summary(&out);
    assert_eq!((rows[0].1.as_str(), rows[1].1.as_str()), ("done", "done"));
    let _ = run(&["--units", "canonical", "--force"]);
    assert_eq!(summary(&out)[0].1, "done");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_batch_refuses_bad_roots_and_outputs() {
    let dir = scratch("batch", "bad");
    let root = dir.join("subjects");
    std::fs::create_dir_all(&root).unwrap();
    std::fs::write(root.join("loose.png"), b"not a subject").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![s(&root), "--out".into(), s(&dir.join("out"))],
            "no subject folders",
        ),
        (
            vec![s(&dir.join("missing")), "--out".into(), s(&dir.join("out"))],
            "missing: not a folder",
        ),
        (
            vec![s(&root.join("loose.png")), "--out".into(), s(&dir.join("out"))],
            "loose.png: not a folder",
        ),
    ];
    for (args, message) in cases {
        let mut all = vec!["batch".to_owned()];
        all.extend(args);
        let output = splineface(&all.iter().map(String::as_str).collect::<Vec<_>>());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains(message), "{message}: {stderr}");
    }
    subject_folder(&root.join("alice"), 2, 3);
    let inside = splineface(&["batch", &s(&root), "--out", &s(&root.join("results"))]);
    let stderr = String::from_utf8_lossy(&inside.stderr);
    assert!(
        stderr.contains("the output lies inside the input folder"),
        "{stderr}"
    );
    assert!(!root.join("results").exists());
    let flag = splineface(&[
        "batch",
        &s(&root),
        "--out",
        &s(&dir.join("o")),
        "--expression-of",
        "x",
    ]);
    assert!(String::from_utf8_lossy(&flag.stderr).contains("no meaning for a batch"));
    assert!(!dir.join("o").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_subject_folder_that_cannot_be_read_is_a_failed_row() {
    // (A folder without read permission cannot be made unreadable to root, who runs CI; one
    // that vanished between the listing and its turn fails the same way, at the same call.)
    let dir = scratch("batch", "unreadable");
    let subject = splineface::batch::Subject {
        name: "gone".into(),
        folder: dir.join("gone"),
    };
    let job = splineface::batch::BatchJob {
        model: None,
        model_identity: "none".into(),
        reference: splineface::reference::ReferenceFace::embedded(),
        reference_identity: "none".into(),
        options: splineface::pipeline::PipelineOptions::default(),
        force: false,
    };
    let row = splineface::batch::run_subject(&subject, &dir.join("out"), &job);
    assert_eq!(row.status, splineface::batch::Status::Failed);
    assert!(
        row.message.contains("cannot read the directory"),
        "{}",
        row.message
    );
    assert!(row.message.contains("gone"), "{}", row.message);
    assert!(!dir.join("out").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
