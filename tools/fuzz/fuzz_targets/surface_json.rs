#![no_main]
//! B-spline surface files, then evaluation of what parses.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data)
        && let Ok(surface) = splineface::bspline::BSplineSurface::from_json(text)
    {
        let (u0, u1) = surface.domain_u();
        let (v0, v1) = surface.domain_v();
        let _ = surface.eval(0.5 * (u0 + u1), 0.5 * (v0 + v1));
        let _ = surface.normal(u0, v1);
    }
});
