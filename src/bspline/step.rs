//! STEP (ISO 10303-21, AP214 "automotive design") export of a B-spline surface, so that CAD
//! tools open the face as the exact spline.

use std::fmt::Write;

use nalgebra::Point3;

use super::{BSplineSurface, KnotVector};
use crate::Real;

/// What goes into a STEP file besides the surface.
#[derive(Debug, Clone, Default)]
pub struct StepOptions<'a> {
    /// The product's name (also the surface's).
    pub name: &'a str,
    /// A line of description (units, origin).
    pub description: &'a str,
    /// The length unit's SI prefix: `true` for millimetres, `false` for no unit conversion
    /// (the file still declares millimetres; the description says what the numbers are).
    pub millimetres: bool,
    /// A closed polyline to add as the face region's outline (3D points on the surface), or
    /// empty.
    pub outline: &'a [Point3<Real>],
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
/// inside a `GEOMETRIC_SET` of a `GEOMETRICALLY_BOUNDED_SURFACE_SHAPE_REPRESENTATION`, with the
/// product structure and unit context CAD readers expect, and optionally the face outline as a
/// `POLYLINE`. The surface is untrimmed: its whole parameter rectangle is written, and the
/// outline shows the face region.
pub fn encode_step(surface: &BSplineSurface, options: &StepOptions<'_>) -> String {
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
    let prefix = if options.millimetres { ".MILLI." } else { "$" };
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
    let mut items = vec![spline];
    if options.outline.len() >= 2 {
        let mut ids: Vec<usize> = options.outline.iter().map(|p| w.point(p)).collect();
        ids.push(ids[0]);
        items.push(w.add(format!("POLYLINE('outline',{})", list(&ids, |k| format!("#{k}")))));
    }
    let set = w.add(format!("GEOMETRIC_SET('',{})", list(&items, |k| format!("#{k}"))));
    let representation = w.add(format!(
        "GEOMETRICALLY_BOUNDED_SURFACE_SHAPE_REPRESENTATION({name},(#{set}),#{representation_context})"
    ));
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
    out
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
