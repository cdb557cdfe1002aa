//! Landmark files: `.pts` and vertex-index lists.

use std::path::Path;

use nalgebra::Point2;
use proptest::prelude::*;
use splineface::landmarks::{
    LandmarkProblem, format_pts, parse_pts, parse_vertex_indices, read_pts, read_vertex_indices,
};

proptest! {
    #[test]
    fn pts_round_trip_is_exact(points in prop::collection::vec(prop::array::uniform2(any::<f64>().prop_filter("finite", |x| x.is_finite())), 0..80)) {
        let points: Vec<Point2<f64>> = points.into_iter().map(|[x, y]| Point2::new(x, y)).collect();
        let back = parse_pts(&format_pts(&points)).unwrap();
        prop_assert_eq!(back, points);
    }
}

#[test]
fn a_typical_pts_file_reads() {
    let text = "version: 1\r\nn_points:  3\r\n{\r\n10.5 20\r\n  -3 4e2\r\n0 0\r\n}\r\n\r\n";
    let p = parse_pts(text).unwrap();
    assert_eq!(
        p,
        vec![
            Point2::new(10.5, 20.0),
            Point2::new(-3.0, 400.0),
            Point2::new(0.0, 0.0)
        ]
    );
}

#[test]
fn malformed_pts_files_are_errors_with_a_line() {
    let cases: [(&str, &str); 10] = [
        ("version: 1\nn_points: 2\n{\n1 2\n", "ends after 1 of 2"),
        ("version: 1\nn_points: 2\n{\n1 2\n}\n", "1 points, expected 2"),
        (
            "version: 1\nn_points: 1\n{\n1 2\n3 4\n}\n",
            "line 5: more than the 1 points",
        ),
        (
            "version: 1\nn_points: 1\n{\nNaN 2\n}\n",
            "line 4: the value is not finite",
        ),
        (
            "version: 1\nn_points: 1\n{\n1 inf\n}\n",
            "line 4: the value is not finite",
        ),
        (
            "version: 1\nn_points: 1\n{\n1 x\n}\n",
            "line 4: `x` is not a number",
        ),
        ("version: 1\n{\n1 2\n}\n", "no n_points"),
        ("version: 1\nn_points: 1000000000000\n{\n", "above the limit"),
        (
            "version: 1\nn_points: 1\n{\n1 2\n}\nextra\n",
            "line 6: text after",
        ),
        ("", "no n_points"),
    ];
    for (text, needle) in cases {
        let message = parse_pts(text).expect_err(text).to_string();
        assert!(message.contains(needle), "{text:?}: {message}");
    }
}

#[test]
fn file_errors_name_the_file() {
    let message = read_pts(Path::new("/no/such/face.pts")).unwrap_err().to_string();
    assert!(
        message.starts_with("/no/such/face.pts: cannot read it"),
        "{message}"
    );
    let dir = std::env::temp_dir().join(format!("splineface-landmarks-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("bad.pts");
    std::fs::write(&file, "version: 1\nn_points: 1\n{\n1\n}\n").unwrap();
    let message = read_pts(&file).unwrap_err().to_string();
    assert!(
        message.contains("bad.pts") && message.contains("line 4"),
        "{message}"
    );
    // A directory where a file belongs.
    assert!(read_pts(&dir).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn vertex_index_lists_read_and_validate() {
    let text = "# header\n3\n\n  7 # trailing comment\n0\n";
    assert_eq!(parse_vertex_indices(text, 3, 8).unwrap(), vec![3, 7, 0]);
    assert!(matches!(
        parse_vertex_indices(text, 3, 7),
        Err(LandmarkProblem::IndexOutOfRange {
            line: 4,
            index: 7,
            vertices: 7
        })
    ));
    assert!(matches!(
        parse_vertex_indices(text, 4, 8),
        Err(LandmarkProblem::WrongCount { got: 3, expected: 4 })
    ));
    assert!(matches!(
        parse_vertex_indices(text, 2, 8),
        Err(LandmarkProblem::WrongCount { got: 3, expected: 2 })
    ));
    assert!(matches!(
        parse_vertex_indices("1\n-2\n", 2, 8),
        Err(LandmarkProblem::Syntax { line: 2, .. })
    ));
    assert!(matches!(
        parse_vertex_indices("1.5\n", 1, 8),
        Err(LandmarkProblem::Syntax { line: 1, .. })
    ));
}

#[test]
#[ignore = "needs ../shared/data/ict-face (not part of the repository)"]
fn the_ict_landmark_indices_read() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-face/landmarks68.txt");
    let indices = read_vertex_indices(&path, 68, 9409).unwrap();
    assert_eq!(indices.len(), 68);
    assert_eq!(indices[0], 1225);
    assert!(
        read_vertex_indices(&path, 68, 1000).is_err(),
        "indices above 1000 exist"
    );
}
