//! Depth maps: analytic shapes against their closed forms, the files read back.

use exr::prelude::{ReadChannels, ReadLayers, ReadSpecificChannel};
use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::mesh::{Raster, TriangleMesh, front_heights};
use splineface::render::{
    DepthMap, View, encode_depth_exr, encode_depth_png, frame_raster, heatmap_png, render_heights, shaded_png,
};

use crate::common::Lcg;

/// A regular grid mesh of `f` over `[-1, 1]²` with `n × n` cells.
fn height_field(n: usize, f: impl Fn(Real, Real) -> Real) -> TriangleMesh {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (
                -1.0 + 2.0 * i as Real / n as Real,
                -1.0 + 2.0 * j as Real / n as Real,
            );
            positions.push(Point3::new(x, y, f(x, y)));
        }
    }
    let mut triangles = Vec::new();
    let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    TriangleMesh::new(positions, triangles).unwrap()
}

/// A UV sphere of radius `r` about the origin.
fn sphere(r: Real, rings: usize, segments: usize) -> TriangleMesh {
    let mut positions = vec![Point3::new(0.0, 0.0, r), Point3::new(0.0, 0.0, -r)];
    for k in 1..rings {
        let theta = std::f64::consts::PI * k as Real / rings as Real;
        for s in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * s as Real / segments as Real;
            positions.push(Point3::new(
                r * theta.sin() * phi.cos(),
                r * theta.sin() * phi.sin(),
                r * theta.cos(),
            ));
        }
    }
    let ring = |k: usize, s: usize| (2 + (k - 1) * segments + s % segments) as u32;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([1, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for k in 1..rings - 1 {
        for s in 0..segments {
            triangles.push([ring(k, s), ring(k + 1, s), ring(k + 1, s + 1)]);
            triangles.push([ring(k, s), ring(k + 1, s + 1), ring(k, s + 1)]);
        }
    }
    TriangleMesh::new(positions, triangles).unwrap()
}

fn raster(size: usize, half: Real) -> Raster {
    let spacing = 2.0 * half / (size - 1) as Real;
    Raster {
        origin: Point2::new(-half, -half),
        spacing,
        width: size,
        height: size,
    }
}

#[test]
fn a_plane_renders_exactly() {
    let f = |x: Real, y: Real| 0.3 * x - 0.7 * y + 2.0;
    let mesh = height_field(7, f);
    let r = raster(101, 1.2);
    let map = DepthMap::render(&mesh, &View::front(), &r);
    let mut covered = 0;
    for j in 0..r.height {
        for i in 0..r.width {
            let p = r.position(i, j);
            let inside = p.x.abs() <= 1.0 + 1e-12 && p.y.abs() <= 1.0 + 1e-12;
            let clearly_inside = p.x.abs() < 1.0 - 1e-9 && p.y.abs() < 1.0 - 1e-9;
            match map.get(i, j) {
                Some(h) => {
                    assert!(inside, "({i}, {j}) covered outside the square");
                    assert!((h - f(p.x, p.y)).abs() < 1e-12, "({i}, {j}): {h}");
                    covered += 1;
                }
                None => assert!(!clearly_inside, "({i}, {j}) missed"),
            }
        }
    }
    assert!(covered > 0);
}

#[test]
fn a_sphere_matches_its_closed_form_to_a_pixel() {
    let radius = 10.0;
    let mesh = sphere(radius, 180, 360);
    let r = raster(201, 11.0);
    let map = DepthMap::render(&mesh, &View::front(), &r);
    let mut worst: Real = 0.0;
    for j in 0..r.height {
        for i in 0..r.width {
            let p = r.position(i, j);
            let rho = p.coords.norm();
            if rho < 0.95 * radius {
                let h = map.get(i, j).expect("inside the disc");
                worst = worst.max((h - (radius * radius - rho * rho).sqrt()).abs());
            } else if rho > 1.0001 * radius {
                assert!(map.get(i, j).is_none(), "({i}, {j}) outside the disc");
            }
        }
    }
    assert!(worst < r.spacing, "worst {worst}, pixel {}", r.spacing);
    // The same sphere seen from any direction gives the same map.
    let turned = DepthMap::render(&mesh, &View::from_yaw_pitch_roll_degrees(30.0, -20.0, 10.0), &r);
    let differ = map
        .heights
        .iter()
        .zip(&turned.heights)
        .filter(|(a, b)| a.is_finite() && b.is_finite() && (*a - *b).abs() > 2.0 * r.spacing)
        .count();
    assert_eq!(differ, 0);
}

#[test]
fn a_view_turns_the_mesh() {
    // The plane z = x seen after a yaw of +45° (nose toward the image's right) is tipped.
    let mesh = height_field(4, |x, _| x);
    let view = View::from_yaw_pitch_roll_degrees(45.0, 0.0, 0.0);
    let r = raster(41, 2.0);
    let map = DepthMap::render(&mesh, &view, &r);
    // Rotating (x, z) = (t, t) by yaw 45° about y: x' = cos·t + sin·t, z' = −sin·t + cos·t = 0.
    for (j, i) in [(20, 20), (10, 12), (30, 25)] {
        if let Some(h) = map.get(i, j) {
            assert!(h.abs() < 1e-9, "{h}");
        }
    }
    assert!(map.covered() > 100);
}

#[test]
fn the_rasteriser_agrees_with_the_reference_rasteriser() {
    let mut rng = Lcg(3);
    let mesh = height_field(13, |x, y| (3.0 * x).sin() * (2.0 * y).cos());
    let jittered: Vec<Point3<Real>> = mesh
        .positions()
        .iter()
        .map(|p| p + nalgebra::Vector3::new(rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), 0.0))
        .collect();
    let mesh = TriangleMesh::new(jittered, mesh.triangles().to_vec()).unwrap();
    let r = raster(300, 1.1);
    let ours = render_heights(mesh.positions(), mesh.triangles(), &r);
    let theirs = front_heights(&mesh, &r);
    let mut both = 0;
    for (a, b) in ours.iter().zip(&theirs) {
        if a.is_finite() && b.is_finite() {
            assert!((a - b).abs() < 1e-9);
            both += 1;
        } else {
            assert_eq!(a.is_finite(), b.is_finite(), "coverage differs");
        }
    }
    assert!(both > 10_000);
}

#[test]
fn depth_files_read_back() {
    let mesh = sphere(5.0, 40, 80);
    let r = frame_raster(mesh.positions().iter().copied(), &View::front(), 64, 48, 0.05).unwrap();
    assert_eq!((r.width, r.height), (64, 48));
    let map = DepthMap::render(&mesh, &View::front(), &r);

    // EXR: Z = −height with A = 1 on the surface, A = 0 elsewhere; rows from the top.
    let exr_bytes = encode_depth_exr(&map).unwrap();
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .specific_channels()
        .required("A")
        .required("Z")
        .collect_pixels(
            |size, _| vec![(0.0_f32, 0.0_f32); size.width() * size.height()],
            |pixels, position, (a, z): (f32, f32)| pixels[position.y() * 64 + position.x()] = (a, z),
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(exr_bytes))
        .unwrap();
    let pixels = &image.layer_data.channel_data.pixels;
    for y in 0..48 {
        for x in 0..64 {
            let (a, z) = pixels[y * 64 + x];
            match map.get(x, 47 - y) {
                Some(h) => assert!(a == 1.0 && (z - (-h as f32)).abs() < 1e-5),
                None => assert!(a == 0.0 && z == 0.0),
            }
        }
    }

    // PNG: 16-bit, 0 = background, the mapping in a text chunk.
    let png_bytes = encode_depth_png(&map).unwrap();
    let decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buffer).unwrap();
    assert_eq!(
        (info.width, info.height, info.bit_depth),
        (64, 48, png::BitDepth::Sixteen)
    );
    let text = &reader.info().uncompressed_latin1_text;
    let mapping = &text
        .iter()
        .find(|t| t.keyword == "splineface-depth")
        .unwrap()
        .text;
    let numbers: Vec<Real> = mapping
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .filter_map(|s| s.parse().ok())
        .collect();
    let (low, step) = (numbers[0], numbers[2]);
    for y in 0..48 {
        for x in 0..64 {
            let value = u16::from_be_bytes([buffer[2 * (y * 64 + x)], buffer[2 * (y * 64 + x) + 1]]);
            match map.get(x, 47 - y) {
                Some(h) => {
                    assert!(value > 0);
                    assert!((low + (value as Real - 1.0) * step - h).abs() <= step);
                }
                None => assert_eq!(value, 0),
            }
        }
    }

    // Preview and heatmap decode to the right sizes.
    let preview = image::load_from_memory(&shaded_png(&map).unwrap()).unwrap();
    assert_eq!((preview.width(), preview.height()), (64, 48));
    let heat = image::load_from_memory(&heatmap_png(&map.heights, 64, 48, 5.0, "mm").unwrap()).unwrap();
    assert_eq!(heat.height(), 48);
    assert!(heat.width() > 64);
}

#[test]
fn views_and_rasters_are_validated() {
    assert!(View::parse("front").is_ok());
    assert!(View::parse("30,-10,5").is_ok());
    for bad in [
        "",
        "side",
        "30,10",
        "30,10,5,1",
        "nan,0,0",
        "200,0,0",
        "1e400,0,0",
    ] {
        assert!(View::parse(bad).is_err(), "{bad}");
    }
    let points = [Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 0.0)];
    assert!(frame_raster(points, &View::front(), 0, 10, 0.0).is_err());
    assert!(frame_raster(points, &View::front(), 10, 20_000, 0.0).is_err());
    assert!(frame_raster(points, &View::front(), 10, 10, -0.1).is_err());
    assert!(frame_raster([], &View::front(), 10, 10, 0.0).is_err());
    assert!(heatmap_png(&[1.0; 4], 3, 3, 1.0, "mm").is_err());
    assert!(heatmap_png(&[1.0; 9], 3, 3, 0.0, "mm").is_err());
}
