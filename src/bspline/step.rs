//! STEP (ISO 10303-21, AP214 "automotive design") export of a B-spline surface, so that CAD
//! tools open the face as the exact spline, whole or trimmed to a region of its domain.

use std::fmt::Write;

use nalgebra::{Point2, Point3};

use super::{BSplineCurve, BSplineError, BSplineSurface, KnotVector};
use crate::Real;
use crate::geometry::LengthUnit;

/// What goes into a STEP file besides the surface.
#[derive(Debug, Clone, Default)]
pub struct StepOptions<'a> {
    /// The product's name (also the surface's).
    pub name: &'a str,
    /// A line of description (units, origin).
    pub description: &'a str,
    /// The length unit the file declares for its numbers (millimetres by default; the numbers
    /// are written as they are, so this says what they already are).
    pub unit: LengthUnit,
    /// A simple closed polygon in the surface's `(u, v)` domain to trim it to (the last
    /// vertex may repeat the first or not; either orientation), or empty for the whole
    /// parameter rectangle.
    pub trim: &'a [Point2<Real>],
}

/// A real in ISO 10303-21 form: a decimal point is mandatory (`1.`, `1.5E-05`).
fn real(x: Real) -> String {
    let text = format!("{x:?}");
    let (mantissa, exponent) = match text.split_once('e') {
        Some((m, e)) => (m.to_owned(), Some(e.to_owned())),
        None => (text, None),
    };
    let mantissa = if mantissa.contains('.') {
        mantissa
    } else {
        format!("{mantissa}.")
    };
    match exponent {
        Some(e) => format!("{mantissa}E{e}"),
        None => mantissa,
    }
}

/// A string parameter: apostrophes doubled, non-ASCII and control characters replaced by `?`
/// (the `\X2\` encoding is legal but poorly supported).
fn string(s: &str) -> String {
    let clean: String = s
        .chars()
        .map(|c| {
            if c.is_ascii() && !c.is_ascii_control() {
                c
            } else {
                '?'
            }
        })
        .collect();
    format!("'{}'", clean.replace('\'', "''").replace('\\', "\\\\"))
}

/// Distinct knots and their multiplicities.
fn knots_and_multiplicities(knots: &KnotVector) -> (Vec<Real>, Vec<usize>) {
    let mut values: Vec<Real> = Vec::new();
    let mut counts: Vec<usize> = Vec::new();
    for &k in knots.knots() {
        if values.last() == Some(&k) {
            *counts.last_mut().expect("counts follow values") += 1;
        } else {
            values.push(k);
            counts.push(1);
        }
    }
    (values, counts)
}

fn list<T>(items: &[T], f: impl Fn(&T) -> String) -> String {
    let inner: Vec<String> = items.iter().map(f).collect();
    format!("({})", inner.join(","))
}

/// Encodes the surface as a STEP AP214 file: a `B_SPLINE_SURFACE_WITH_KNOTS` (the control grid,
/// degrees and knots exactly as in the kernel, numbers in their shortest exact decimal form)
/// with the product structure and unit context CAD readers expect.
///
/// * Without a trim, the surface's whole parameter rectangle, in a `GEOMETRIC_SET` of a
///   `GEOMETRICALLY_BOUNDED_SURFACE_SHAPE_REPRESENTATION`.
/// * With one, a trimmed face: an `ADVANCED_FACE` on the surface in an `OPEN_SHELL` of a
///   `SHELL_BASED_SURFACE_MODEL` (a `MANIFOLD_SURFACE_SHAPE_REPRESENTATION`), bounded by one
///   closed edge. The edge is a `SURFACE_CURVE` of two exact representations with the same
///   parameter `t`: in space, the polygon's image on the surface
///   ([`BSplineSurface::image_of_polyline`], a `B_SPLINE_CURVE_WITH_KNOTS` of degree
///   `p + q`), and in the surface's domain (`PCURVE`), the polygon itself as a degree-1
///   B-spline, side `k` over `t ∈ [k, k + 1]`. The loop runs counter-clockwise in `(u, v)`, so
///   the face keeps the surface's orientation (`∂F/∂u × ∂F/∂v`).
///
/// # Errors
/// From [`BSplineSurface::image_of_polyline`], for a trim polygon outside the domain, with
/// fewer than 3 distinct vertices ([`BSplineError::PolylineTooShort`]), enclosing no area
/// ([`BSplineError::DegenerateTrim`]) or on a surface that jumps across a knot line.
///
/// # Examples
///
/// ```
/// use nalgebra::{Point2, Point3};
/// use splineface::bspline::{BSplineSurface, KnotVector, StepOptions, encode_step};
///
/// let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0)?;
/// let grid = (0..16).map(|i| Point3::new((i / 4) as f64, (i % 4) as f64, ((i * 5) % 3) as f64)).collect();
/// let surface = BSplineSurface::new(k.clone(), k, 4, 4, grid)?;
/// // The whole rectangle, then a face trimmed to a triangle of the domain.
/// let whole = encode_step(&surface, &StepOptions { name: "patch", ..Default::default() })?;
/// assert!(whole.starts_with("ISO-10303-21;") && whole.contains("B_SPLINE_SURFACE_WITH_KNOTS"));
/// assert!(!whole.contains("ADVANCED_FACE"));
/// let triangle = [Point2::new(0.1, 0.1), Point2::new(0.9, 0.2), Point2::new(0.4, 0.8)];
/// let trimmed = encode_step(&surface, &StepOptions { name: "patch", trim: &triangle, ..Default::default() })?;
/// assert!(trimmed.contains("ADVANCED_FACE") && trimmed.contains("PCURVE"));
/// // Two vertices enclose nothing.
/// assert!(encode_step(&surface, &StepOptions { trim: &triangle[..2], ..Default::default() }).is_err());
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
pub fn encode_step(surface: &BSplineSurface, options: &StepOptions<'_>) -> Result<String, BSplineError> {
    let trim = if options.trim.is_empty() {
        None
    } else {
        Some(TrimLoop::new(surface, options.trim)?)
    };
    let mut w = Entities::default();
    let context = w.add("APPLICATION_CONTEXT('automotive design')".into());
    w.add(format!(
        "APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,#{context})"
    ));
    let product_context = w.add(format!("PRODUCT_CONTEXT('',#{context},'mechanical')"));
    let definition_context = w.add(format!(
        "PRODUCT_DEFINITION_CONTEXT('part definition',#{context},'design')"
    ));
    let name = string(options.name);
    let product = w.add(format!(
        "PRODUCT({name},{name},{},(#{product_context}))",
        string(options.description)
    ));
    let formation = w.add(format!("PRODUCT_DEFINITION_FORMATION('','',#{product})"));
    let definition = w.add(format!(
        "PRODUCT_DEFINITION('design','',#{formation},#{definition_context})"
    ));
    let shape = w.add(format!("PRODUCT_DEFINITION_SHAPE('','',#{definition})"));
    let prefix = match options.unit {
        LengthUnit::Millimetre => ".MILLI.",
        LengthUnit::Centimetre => ".CENTI.",
        LengthUnit::Metre => "$",
    };
    let length = w.add(format!("(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT({prefix},.METRE.))"));
    let angle = w.add("(NAMED_UNIT(*)PLANE_ANGLE_UNIT()SI_UNIT($,.RADIAN.))".into());
    let solid = w.add("(NAMED_UNIT(*)SI_UNIT($,.STERADIAN.)SOLID_ANGLE_UNIT())".into());
    let uncertainty = w.add(format!(
        "UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-06),#{length},'distance_accuracy_value','')"
    ));
    let representation_context = w.add(format!(
        "(GEOMETRIC_REPRESENTATION_CONTEXT(3)GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#{uncertainty}))\
         GLOBAL_UNIT_ASSIGNED_CONTEXT((#{length},#{angle},#{solid}))REPRESENTATION_CONTEXT('',''))"
    ));

    let rows: Vec<String> = (0..surface.rows())
        .map(|i| {
            let row: Vec<usize> = (0..surface.cols())
                .map(|j| w.point(surface.control_point(i, j)))
                .collect();
            list(&row, |k| format!("#{k}"))
        })
        .collect();
    let (ku, mu) = knots_and_multiplicities(surface.knots_u());
    let (kv, mv) = knots_and_multiplicities(surface.knots_v());
    let spline = w.add(format!(
        "B_SPLINE_SURFACE_WITH_KNOTS({name},{},{},({}),.UNSPECIFIED.,.F.,.F.,.F.,{},{},{},{},.UNSPECIFIED.)",
        surface.degree_u(),
        surface.degree_v(),
        rows.join(","),
        list(&mu, |m| m.to_string()),
        list(&mv, |m| m.to_string()),
        list(&ku, |&k| real(k)),
        list(&kv, |&k| real(k)),
    ));
    let representation = match &trim {
        None => {
            let set = w.add(format!("GEOMETRIC_SET('',(#{spline}))"));
            w.add(format!(
                "GEOMETRICALLY_BOUNDED_SURFACE_SHAPE_REPRESENTATION({name},(#{set}),#{representation_context})"
            ))
        }
        Some(trim) => {
            let shell = trim.write(&mut w, spline, &name);
            let origin = w.point(&Point3::origin());
            let z = w.add("DIRECTION('',(0.,0.,1.))".into());
            let x = w.add("DIRECTION('',(1.,0.,0.))".into());
            let axes = w.add(format!("AXIS2_PLACEMENT_3D('',#{origin},#{z},#{x})"));
            w.add(format!(
                "MANIFOLD_SURFACE_SHAPE_REPRESENTATION({name},(#{axes},#{shell}),#{representation_context})"
            ))
        }
    };
    w.add(format!(
        "SHAPE_DEFINITION_REPRESENTATION(#{shape},#{representation})"
    ));

    let mut out = String::with_capacity(w.data.len() + 512);
    out.push_str("ISO-10303-21;\nHEADER;\n");
    let _ = writeln!(out, "FILE_DESCRIPTION(({}),'2;1');", string(options.description));
    let _ = writeln!(
        out,
        "FILE_NAME({name},'',(''),(''),'splineface {}','splineface','');",
        env!("CARGO_PKG_VERSION")
    );
    out.push_str("FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n");
    out.push_str(&w.data);
    out.push_str("ENDSEC;\nEND-ISO-10303-21;\n");
    Ok(out)
}

/// A trimming loop: the polygon counter-clockwise, closed, without repeated vertices, and its
/// image on the surface.
struct TrimLoop {
    /// `n + 1` vertices, the last the first again.
    polygon: Vec<Point2<Real>>,
    /// The image, over `t ∈ [0, n]` like the polygon.
    edge: BSplineCurve,
}

impl TrimLoop {
    fn new(surface: &BSplineSurface, trim: &[Point2<Real>]) -> Result<Self, BSplineError> {
        let mut polygon: Vec<Point2<Real>> = trim.to_vec();
        polygon.dedup();
        while polygon.len() > 1 && polygon.first() == polygon.last() {
            polygon.pop();
        }
        if polygon.len() < 3 {
            return Err(BSplineError::PolylineTooShort {
                distinct: polygon.len(),
                needed: 3,
            });
        }
        let area = crate::geometry::signed_area(&polygon);
        if area == 0.0 {
            return Err(BSplineError::DegenerateTrim);
        }
        if area < 0.0 {
            polygon.reverse();
        }
        polygon.push(polygon[0]);
        let edge = surface.image_of_polyline(&polygon)?;
        Ok(TrimLoop { polygon, edge })
    }

    /// Writes the loop's topology and geometry on `surface` (an entity already written);
    /// returns the `SHELL_BASED_SURFACE_MODEL`.
    fn write(&self, w: &mut Entities, surface: usize, name: &str) -> usize {
        let (knots, multiplicities) = knots_and_multiplicities(self.edge.knots());
        let points: Vec<usize> = self.edge.control_points().iter().map(|p| w.point(p)).collect();
        let curve = w.add(format!(
            "B_SPLINE_CURVE_WITH_KNOTS('',{},{},.UNSPECIFIED.,.T.,.F.,{},{},.UNSPECIFIED.)",
            self.edge.degree(),
            list(&points, |k| format!("#{k}")),
            list(&multiplicities, |m| m.to_string()),
            list(&knots, |&k| real(k)),
        ));
        // The polygon as a degree-1 B-spline: a knot at every vertex, ends clamped.
        let uv: Vec<usize> = self
            .polygon
            .iter()
            .map(|p| w.add(format!("CARTESIAN_POINT('',({},{}))", real(p.x), real(p.y))))
            .collect();
        let sides = self.polygon.len() - 1;
        let mut uv_multiplicities = vec![1; sides + 1];
        uv_multiplicities[0] = 2;
        uv_multiplicities[sides] = 2;
        let uv_knots: Vec<Real> = (0..=sides).map(|k| k as Real).collect();
        let uv_curve = w.add(format!(
            "B_SPLINE_CURVE_WITH_KNOTS('',1,{},.POLYLINE_FORM.,.T.,.F.,{},{},.UNSPECIFIED.)",
            list(&uv, |k| format!("#{k}")),
            list(&uv_multiplicities, |m| m.to_string()),
            list(&uv_knots, |&k| real(k)),
        ));
        let plane = w.add(
            "(GEOMETRIC_REPRESENTATION_CONTEXT(2)PARAMETRIC_REPRESENTATION_CONTEXT()\
             REPRESENTATION_CONTEXT('2D SPACE',''))"
                .into(),
        );
        let in_domain = w.add(format!("DEFINITIONAL_REPRESENTATION('',(#{uv_curve}),#{plane})"));
        let pcurve = w.add(format!("PCURVE('',#{surface},#{in_domain})"));
        let both = w.add(format!("SURFACE_CURVE('',#{curve},(#{pcurve}),.PCURVE_S1.)"));
        let start = w.point(&self.edge.control_points()[0]);
        let vertex = w.add(format!("VERTEX_POINT('',#{start})"));
        let edge = w.add(format!("EDGE_CURVE('',#{vertex},#{vertex},#{both},.T.)"));
        let oriented = w.add(format!("ORIENTED_EDGE('',*,*,#{edge},.T.)"));
        let edge_loop = w.add(format!("EDGE_LOOP('',(#{oriented}))"));
        let bound = w.add(format!("FACE_OUTER_BOUND('',#{edge_loop},.T.)"));
        let face = w.add(format!("ADVANCED_FACE({name},(#{bound}),#{surface},.T.)"));
        let shell = w.add(format!("OPEN_SHELL('',(#{face}))"));
        w.add(format!("SHELL_BASED_SURFACE_MODEL('',(#{shell}))"))
    }
}

/// The data section being written: entity instances numbered from 1.
#[derive(Default)]
struct Entities {
    data: String,
    count: usize,
}

impl Entities {
    fn add(&mut self, text: String) -> usize {
        self.count += 1;
        let _ = writeln!(self.data, "#{}={text};", self.count);
        self.count
    }

    fn point(&mut self, p: &Point3<Real>) -> usize {
        self.add(format!(
            "CARTESIAN_POINT('',({},{},{}))",
            real(p.x),
            real(p.y),
            real(p.z)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reals_have_a_decimal_point() {
        assert_eq!(real(1.0), "1.0");
        assert_eq!(real(-3.0), "-3.0");
        assert_eq!(real(1e-5), "1.E-5");
        assert_eq!(real(1.5e-7), "1.5E-7");
        assert_eq!(real(2e21), "2.E21");
        assert_eq!(real(0.1), "0.1");
        for x in [0.1, 1e-5, 1.5e-7, 2e21, -123.456, 1.0 / 3.0] {
            let parsed: Real = real(x).replace(".E", ".0E").parse().unwrap();
            assert_eq!(parsed, x);
        }
    }

    #[test]
    fn strings_are_escaped() {
        assert_eq!(string("it's"), "'it''s'");
        assert_eq!(string("é\n"), "'??'");
    }
}
