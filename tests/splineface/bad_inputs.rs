//! The bad-input corpus (`tests/data/bad-inputs/`, made by `tools/make-bad-inputs.py`), fed
//! through the command line: every file, and every bad flag or output path below, must end in
//! exit status 1 (not a panic's 101), a message naming the file or flag and the problem, and no
//! output left behind, temporary files included.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use splineface::demo::{SceneOptions, scene};

/// How a corpus file is fed to the program.
#[derive(Debug, Clone, Copy)]
enum Kind {
    /// A landmark file among the landmark files of a points-only run.
    Landmarks,
    /// A mesh to `render-depth`.
    Mesh,
    /// A `--reference` face.
    Reference,
    /// A surface to `inspect`.
    Surface,
    /// A `--landmark-model`.
    Model,
    /// A photo in a batch, with a good landmark file.
    Photo,
}

use Kind::*;

/// Every corpus file, its kind, and what the message must say about it (besides its path).
const CORPUS: &[(&str, Kind, &str)] = &[
    ("empty.pts", Landmarks, "the file is empty"),
    ("truncated.pts", Landmarks, "line 18: expected two numbers `x y`"),
    ("wrong-count.pts", Landmarks, "67 points, expected 68"),
    ("nan.pts", Landmarks, "line 4: the value is not finite"),
    ("inf.pts", Landmarks, "line 9: the value is not finite"),
    ("huge-number.pts", Landmarks, "line 13: the value is not finite"),
    ("huge-count.pts", Landmarks, "above the limit 100000"),
    (
        "negative-count.pts",
        Landmarks,
        "line 2: n_points `-68` is not a count",
    ),
    ("utf16.pts", Landmarks, "the text is UTF-16; save it as UTF-8"),
    ("latin1.pts", Landmarks, "not UTF-8 text (byte 11)"),
    ("binary.pts", Landmarks, "not UTF-8 text"),
    ("12-points.pts", Landmarks, "12 points; expected 68 (iBUG) or 40"),
    ("three-columns.pts", Landmarks, "line 4: more than two numbers"),
    ("empty.json", Landmarks, "the file is empty"),
    (
        "truncated.json",
        Landmarks,
        "line 1: EOF while parsing a value (column 300)",
    ),
    ("wrong-count.json", Landmarks, "67 points, expected 68"),
    (
        "huge-number.json",
        Landmarks,
        "line 1: number out of range (column 86)",
    ),
    (
        "string-numbers.json",
        Landmarks,
        "invalid type: string \"100.0\", expected f64",
    ),
    (
        "one-coordinate.json",
        Landmarks,
        "the points have 1 coordinates each, expected 2 or 3",
    ),
    (
        "mixed-dimensions.json",
        Landmarks,
        "point 67 has 3 coordinates, the first has 2",
    ),
    ("not-an-object.json", Landmarks, "expected a JSON object"),
    (
        "wrong-format.json",
        Landmarks,
        "format is \"something/else\", expected \"splineface/landmarks\"",
    ),
    ("unknown-scheme.json", Landmarks, "unknown variant `ibug98`"),
    ("utf16.json", Landmarks, "the text is UTF-16; save it as UTF-8"),
    ("empty.obj", Mesh, "the file is empty"),
    ("nan.obj", Mesh, "line 3: a coordinate is not finite"),
    (
        "index-out-of-range.obj",
        Mesh,
        "index 4 is out of range (3 vertices)",
    ),
    (
        "zero-index.obj",
        Mesh,
        "line 4: index 0 is out of range (3 vertices)",
    ),
    ("no-triangles.obj", Mesh, "no triangles"),
    ("huge-number.obj", Mesh, "line 2: a coordinate is not finite"),
    ("utf16.obj", Mesh, "the text is UTF-16; save it as UTF-8"),
    ("binary.obj", Mesh, "the file is not UTF-8 text (byte 4)"),
    (
        "truncated.ply",
        Mesh,
        "the file is truncated: vertex 10 is incomplete",
    ),
    (
        "huge-count.ply",
        Mesh,
        "the file is truncated: vertex 4 is incomplete",
    ),
    (
        "bad-header.ply",
        Mesh,
        "header line 4: unexpected `property float`",
    ),
    (
        "binary-truncated.ply",
        Mesh,
        "the file is truncated: vertex 1 is incomplete",
    ),
    ("empty.glb", Mesh, "the file is empty"),
    (
        "huge-claim.glb",
        Mesh,
        "the header says 3000000000 bytes, the file has 22",
    ),
    (
        "garbage.gltf",
        Mesh,
        "glTF: key must be a string at line 1 column 3",
    ),
    ("device-buffer.gltf", Mesh, "/dev/zero is not a regular file"),
    ("missing-buffer.gltf", Mesh, "buffer 0: "),
    ("remote-buffer.gltf", Mesh, "only files and data: URIs are read"),
    ("empty-reference.json", Reference, "the file is empty"),
    (
        "truncated-reference.json",
        Reference,
        "EOF while parsing a list at line 1 column 34815",
    ),
    (
        "short-structure-reference.json",
        Reference,
        "structure has 39 points, expected 40",
    ),
    (
        "short-grid-reference.json",
        Reference,
        "1023 control points given for a 32 × 32 grid",
    ),
    (
        "future-reference.json",
        Reference,
        "format version 99 is not supported (this build reads versions 1 to 5)",
    ),
    (
        "short-space-reference.json",
        Reference,
        "space: the grid holds 12276 bytes; 1 modes of 1024 control points need 12288",
    ),
    (
        "early-landmarks-reference.json",
        Reference,
        "space landmarks need format version 5",
    ),
    (
        "short-landmarks-reference.json",
        Reference,
        "space landmarks: the grid holds 804 bytes; 1 modes of 68 landmarks need 816",
    ),
    ("empty-surface.json", Surface, "the file is empty"),
    (
        "truncated-surface.json",
        Surface,
        "EOF while parsing a value at line 1 column 21550",
    ),
    (
        "decreasing-knots-surface.json",
        Surface,
        "knots must not decrease: knot 6 is 0.06896551724137931, after 0.10344827586206896",
    ),
    (
        "degree-99-surface.json",
        Surface,
        "degree 99 is above the supported maximum 15",
    ),
    (
        "rows-mismatch-surface.json",
        Surface,
        "control grid is 33 × 32 but the knots need 32 × 32",
    ),
    (
        "huge-number-surface.json",
        Surface,
        "number out of range at line 1 column 1392",
    ),
    (
        "utf16-surface.json",
        Surface,
        "the text is UTF-16; save it as UTF-8",
    ),
    ("empty.dat", Model, "the file is empty"),
    ("text.dat", Model, "at byte 0: bad integer control byte 0x74"),
    (
        "huge-count.dat",
        Model,
        "the forests claims 1000000000000 items, more than the file holds",
    ),
    (
        "wrong-version.dat",
        Model,
        "version 7; this reader knows version 1",
    ),
    (
        "truncated.dat",
        Model,
        "at byte 2: a 2×1 matrix is larger than the file",
    ),
    ("empty.png", Photo, "cannot read the image: the file is empty"),
    ("truncated.png", Photo, "cannot read the image"),
    ("text.png", Photo, "cannot read the image"),
    ("tiny.png", Photo, "8×8 pixels: too small"),
    ("flat.png", Photo, "no contrast"),
    (
        "huge-header.png",
        Photo,
        "100000×100000 pixels: larger than 100 megapixels",
    ),
    ("binary.jpg", Photo, "cannot read the image"),
];

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bad-inputs")
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_owned()
}

/// Every path under `dir`, relative to it.
fn listing(dir: &Path) -> BTreeSet<PathBuf> {
    let mut out = BTreeSet::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            out.insert(path.strip_prefix(dir).unwrap().to_path_buf());
            if path.is_dir() && !path.is_symlink() {
                stack.push(path);
            }
        }
    }
    out
}

/// A scratch folder with three good photos and their landmark files in `good/`.
struct Bench {
    dir: PathBuf,
    good: PathBuf,
}

impl Bench {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("splineface-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let good = dir.join("good");
        std::fs::create_dir_all(&good).unwrap();
        let scene = scene(&SceneOptions {
            photos: 3,
            ..SceneOptions::default()
        })
        .unwrap();
        for (path, bytes) in scene.files().unwrap() {
            std::fs::write(good.join(path), bytes).unwrap();
        }
        Bench { dir, good }
    }

    /// A fresh folder for one case.
    fn case_dir(&self, name: &str) -> PathBuf {
        let dir = self.dir.join("cases").join(name);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The arguments that feed `file` as `kind`, run in `dir`; they write into `dir/out`.
    fn arguments(&self, file: &Path, kind: Kind, dir: &Path) -> Vec<String> {
        let out = s(&dir.join("out"));
        let good_photo = |to: &Path| {
            for ext in ["png", "pts"] {
                let name = format!("photo01.{ext}");
                std::fs::copy(self.good.join(&name), to.join(&name)).unwrap();
            }
        };
        match kind {
            Landmarks => {
                let landmarks = dir.join("landmarks");
                std::fs::create_dir_all(&landmarks).unwrap();
                std::fs::copy(self.good.join("photo01.pts"), landmarks.join("photo01.pts")).unwrap();
                std::fs::copy(file, landmarks.join(file.file_name().unwrap())).unwrap();
                vec![
                    "reconstruct".into(),
                    "--landmarks".into(),
                    s(&landmarks),
                    "--out".into(),
                    out,
                ]
            }
            Mesh => vec![
                "render-depth".into(),
                s(file),
                "--out".into(),
                s(&dir.join("out.exr")),
                "--preview".into(),
                s(&dir.join("preview.png")),
            ],
            Reference => vec![
                "reconstruct".into(),
                "--landmarks".into(),
                s(&self.good),
                "--reference".into(),
                s(file),
                "--out".into(),
                out,
            ],
            Surface => vec!["inspect".into(), s(file)],
            Model => {
                let photos = dir.join("photos");
                std::fs::create_dir_all(&photos).unwrap();
                std::fs::copy(self.good.join("photo01.png"), photos.join("photo01.png")).unwrap();
                vec![
                    "reconstruct".into(),
                    "--photos".into(),
                    s(&photos),
                    "--landmark-model".into(),
                    s(file),
                    "--out".into(),
                    out,
                ]
            }
            Photo => {
                let photos = dir.join("photos");
                std::fs::create_dir_all(&photos).unwrap();
                good_photo(&photos);
                std::fs::copy(file, photos.join(file.file_name().unwrap())).unwrap();
                let stem = file.file_stem().unwrap().to_str().unwrap();
                std::fs::copy(self.good.join("photo02.pts"), photos.join(format!("{stem}.pts"))).unwrap();
                vec![
                    "reconstruct".into(),
                    "--photos".into(),
                    s(&photos),
                    "--landmarks".into(),
                    s(&photos),
                    "--out".into(),
                    out,
                ]
            }
        }
    }
}

/// Runs the program; checks exit status 1, no panic, the message holds every `expected` piece,
/// and `dir` holds afterwards exactly what it held before.
fn fails_cleanly(args: &[String], dir: &Path, expected: &[&str]) -> Result<(), String> {
    let before = listing(dir);
    let run = Command::new(env!("CARGO_BIN_EXE_splineface"))
        .args(args)
        .env_remove("SPLINEFACE_LANDMARK_MODEL")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    let mut problems = Vec::new();
    if run.status.code() != Some(1) {
        problems.push(format!("exit status {:?}", run.status.code()));
    }
    if stderr.contains("panicked") {
        problems.push("a panic".to_owned());
    }
    for piece in expected {
        if !stderr.contains(piece) {
            problems.push(format!("no {piece:?} in the message"));
        }
    }
    let after = listing(dir);
    if after != before {
        let left: Vec<_> = after.difference(&before).collect();
        problems.push(format!("left behind: {left:?}"));
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(format!("{args:?}: {}\n  stderr: {stderr}", problems.join("; ")))
    }
}

#[test]
fn every_bad_file_fails_cleanly_naming_itself_and_the_problem() {
    let bench = Bench::new("bad-files");
    let files: BTreeSet<String> = std::fs::read_dir(corpus())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    let listed: BTreeSet<String> = CORPUS.iter().map(|(name, ..)| (*name).to_owned()).collect();
    assert_eq!(files, listed, "every corpus file needs a case, every case a file");
    let mut failures = Vec::new();
    for &(name, kind, problem) in CORPUS {
        let dir = bench.case_dir(name);
        let file = corpus().join(name);
        let args = bench.arguments(&file, kind, &dir);
        if let Err(e) = fails_cleanly(&args, &dir, &[name, problem]) {
            failures.push(format!("{name}: {e}"));
        }
    }
    std::fs::remove_dir_all(&bench.dir).unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} cases:\n{}",
        failures.len(),
        CORPUS.len(),
        failures.join("\n")
    );
}

/// Directories and pipes where files belong, output paths that cannot be written, and flags
/// out of range: each refused up front, naming the path or flag.
#[test]
fn bad_paths_and_flags_fail_cleanly() {
    let bench = Bench::new("bad-paths");
    let dir = bench.case_dir("paths-and-flags");
    let at = |name: &str| s(&dir.join(name));
    std::fs::write(dir.join("triangle.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(dir.join("a-file"), "x").unwrap();
    std::fs::create_dir_all(dir.join("folder.obj")).unwrap();
    std::fs::create_dir_all(dir.join("folder.exr")).unwrap();
    // A named pipe: opening it would block until someone writes to it.
    let pipe = Command::new("mkfifo")
        .arg(dir.join("pipe.json"))
        .status()
        .is_ok_and(|s| s.success());
    let good = s(&bench.good);
    let args = |list: &[&str]| list.iter().map(|a| (*a).to_owned()).collect::<Vec<String>>();
    // A points-only reconstruction with one flag set.
    let with_flag = |flag: &str, value: &str| {
        args(&[
            "reconstruct",
            "--landmarks",
            &good,
            "--out",
            &at("out"),
            flag,
            value,
        ])
    };
    let mut cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (
            args(&["landmarks", &at("a-file"), "--out", &at("out")]),
            vec!["--landmark-model PATH is needed"],
        ),
        (
            args(&["landmarks", &at("missing.png"), "--out", &at("out")]),
            vec!["missing.png: no such file"],
        ),
        (
            args(&["landmarks", "--out", &at("out")]),
            vec!["no photos: give PHOTO... or --photos DIR"],
        ),
        (
            args(&[
                "landmarks",
                &at("a-file"),
                "--landmark-model",
                &at("folder.obj"),
                "--out",
                &at("out"),
            ]),
            vec!["folder.obj", "it is a directory, not a file"],
        ),
        (
            args(&[
                "landmarks",
                &at("a-file"),
                "--landmark-model",
                &at("a-file"),
                "--out",
                &at("a-file/sub"),
            ]),
            vec!["a-file/sub: cannot be created"],
        ),
        (
            args(&["render-depth", &at("folder.obj"), "--out", &at("o.exr")]),
            vec!["folder.obj: it is a directory, not a file"],
        ),
        (
            args(&["inspect", &at("folder.obj")]),
            vec!["folder.obj: it is a directory, not a file"],
        ),
        (
            args(&[
                "reconstruct",
                "--landmarks",
                &good,
                "--landmark-model",
                &at("folder.obj"),
                "--out",
                &at("out"),
            ]),
            vec!["folder.obj", "it is a directory, not a file"],
        ),
        (
            args(&[
                "reconstruct",
                "--landmarks",
                &at("triangle.obj"),
                "--out",
                &at("out"),
            ]),
            vec!["cannot read the directory", "triangle.obj"],
        ),
        (
            args(&["render-depth", &at("triangle.obj"), "--out", &at("folder.exr")]),
            vec!["folder.exr: is a directory"],
        ),
        (
            args(&["render-depth", &at("triangle.obj"), "--out", &at("missing/o.exr")]),
            vec!["missing/o.exr: the directory", "does not exist"],
        ),
        (
            args(&["render-depth", &at("triangle.obj"), "--out", &at("a-file/o.exr")]),
            vec!["a-file/o.exr", "a-file is not a directory"],
        ),
        (
            args(&[
                "render-depth",
                &at("triangle.obj"),
                "--out",
                &at("o.exr"),
                "--preview",
                &at("a-file/p.png"),
            ]),
            vec!["a-file/p.png", "a-file is not a directory"],
        ),
        (
            args(&["render-depth", &at("triangle.obj"), "--out", &at("o.txt")]),
            vec!["o.txt: the depth map must be .exr or .png"],
        ),
        (
            args(&["reconstruct", "--landmarks", &good, "--out", &at("a-file")]),
            vec!["a-file: exists and is not a directory"],
        ),
        (
            args(&["reconstruct", "--landmarks", &good, "--out", &at("a-file/sub")]),
            vec!["a-file/sub: cannot be created", "a-file is not a directory"],
        ),
        (
            args(&["demo", "--out", &at("a-file/demo"), "--photos", "3"]),
            vec!["a-file/demo: cannot be created"],
        ),
        (
            args(&[
                "reconstruct",
                "--landmarks",
                &good,
                "--out",
                "/proc/splineface-cannot-be-here",
            ]),
            vec!["/proc/splineface-cannot-be-here: cannot write there"],
        ),
        (
            args(&[
                "fit-reference",
                "--mesh",
                &at("triangle.obj"),
                "--landmarks",
                &at("a-file"),
                "--out",
                &at("a-file/r.json"),
            ]),
            vec!["a-file/r.json", "is not a directory"],
        ),
        (
            args(&[
                "fit-reference",
                "--mesh",
                &at("triangle.obj"),
                "--landmarks",
                &at("a-file"),
                "--out",
                &at("r.json"),
                "--grid",
                "1",
            ]),
            vec!["grid", "1"],
        ),
        (
            args(&[
                "fit-reference",
                "--mesh",
                &at("triangle.obj"),
                "--landmarks",
                &at("a-file"),
                "--out",
                &at("r.json"),
                "--smoothness",
                "NaN",
            ]),
            vec!["smoothness", "NaN"],
        ),
        (
            with_flag("--spacing", "NaN"),
            vec!["--spacing NaN: must be between 0.1 and 20"],
        ),
        (
            with_flag("--expression-sigma", "0"),
            vec!["--expression-sigma 0: must be positive"],
        ),
        (
            with_flag("--expression-of", "no-such-photo"),
            vec!["--expression-of no-such-photo: no usable photo has that name (the photos are "],
        ),
        (
            with_flag("--eye-distance", "-63"),
            vec!["--eye-distance -63: must be positive"],
        ),
        (
            with_flag("--depth-size", "99999999"),
            vec!["--depth-size 99999999: must be between 16 and"],
        ),
        (
            with_flag("--texture-size", "8"),
            vec!["--texture-size 8: must be between 16 and 8192"],
        ),
        (
            with_flag("--texture-size", "big"),
            vec!["--texture-size big: expected auto or a whole number of texels (16 to 8192)"],
        ),
        (
            with_flag("--min-photos", "0"),
            vec!["--min-photos 0: must be at least 1"],
        ),
        (
            with_flag("--min-photos", "4"),
            vec!["3 usable photos, at least 4 needed"],
        ),
        (
            with_flag("--units", "inches"),
            vec!["--units `inches`: expected mm or canonical"],
        ),
        (
            args(&["demo", "--out", &at("out"), "--noise", "inf"]),
            vec!["--noise inf: must be a finite percentage"],
        ),
        (
            args(&["demo", "--out", &at("out"), "--noise", "-1"]),
            vec!["--noise -1: must be a finite percentage"],
        ),
        (
            args(&["demo", "--out", &at("out"), "--photos", "100000"]),
            vec!["--photos 100000: between 1 and 200"],
        ),
        (
            args(&[
                "render-depth",
                &at("triangle.obj"),
                "--out",
                &at("o.exr"),
                "--size",
                "0x5",
            ]),
            vec!["--size `0x5`"],
        ),
        (
            args(&[
                "render-depth",
                &at("triangle.obj"),
                "--out",
                &at("o.exr"),
                "--view",
                "1,nan,2",
            ]),
            vec!["--view: `1,nan,2` is not a view"],
        ),
        (
            args(&[
                "compare",
                &at("triangle.obj"),
                &at("triangle.obj"),
                "--out",
                &at("out"),
                "--max",
                "-1",
            ]),
            vec!["--max -1: must be a positive number of millimetres"],
        ),
        (
            args(&[
                "compare",
                &at("triangle.obj"),
                &at("triangle.obj"),
                "--out",
                &at("out"),
                "--size",
                "0",
            ]),
            vec!["--size 0: must be between 16 and"],
        ),
        (
            args(&[
                "compare",
                &at("triangle.obj"),
                &at("triangle.obj"),
                "--out",
                &at("out"),
                "--truth-units",
                "furlong",
            ]),
            vec!["--truth-units `furlong`: expected mm, cm or m"],
        ),
    ];
    if pipe {
        cases.push((
            args(&["inspect", &at("pipe.json")]),
            vec!["pipe.json: it is not a regular file (a device, pipe or socket)"],
        ));
        cases.push((
            args(&[
                "reconstruct",
                "--landmarks",
                &good,
                "--reference",
                &at("pipe.json"),
                "--out",
                &at("out"),
            ]),
            vec!["pipe.json: it is not a regular file"],
        ));
    }
    let failures: Vec<String> = cases
        .iter()
        .filter_map(|(args, expected)| fails_cleanly(args, &dir, expected).err())
        .collect();
    std::fs::remove_dir_all(&bench.dir).unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} cases:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
