//! A small seeded random generator: the same numbers on every machine and in every version,
//! for the demo's scenes and for reproducible synthetic data in tools, tests and benchmarks
//! (which must not depend on a crate's random stream, which may change between releases).

use nalgebra::Point3;

use crate::Real;

/// A 64-bit linear congruential generator with Knuth's MMIX constants. Not for anything that
/// needs statistical quality beyond jittering poses and noise, and never for security.
///
/// # Examples
/// ```
/// use splineface::random::Lcg;
///
/// let mut a = Lcg(7);
/// let mut b = Lcg(7);
/// let x = a.uniform(-1.0, 1.0);
/// assert!((-1.0..1.0).contains(&x));
/// assert_eq!(x, b.uniform(-1.0, 1.0)); // the same seed, the same numbers
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lcg(pub u64);

impl Lcg {
    /// Uniform in `[0, 1)`, with 53 random bits.
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> Real {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as Real / (1u64 << 53) as Real
    }

    /// Uniform in `[a, b)`.
    pub fn uniform(&mut self, a: Real, b: Real) -> Real {
        a + (b - a) * self.next()
    }

    /// A point uniform in the box `[lo, hi]`: [`Lcg::uniform`] for `x`, then `y`, then `z`.
    ///
    /// # Examples
    /// ```
    /// use splineface::random::Lcg;
    ///
    /// let (mut a, mut b) = (Lcg(3), Lcg(3));
    /// let p = a.point_in([0.0, -1.0, 5.0], [1.0, 1.0, 6.0]);
    /// assert!((0.0..1.0).contains(&p.x) && (-1.0..1.0).contains(&p.y) && (5.0..6.0).contains(&p.z));
    /// assert_eq!(p.x, b.uniform(0.0, 1.0)); // the coordinates in that order
    /// assert_eq!(p.y, b.uniform(-1.0, 1.0));
    /// ```
    pub fn point_in(&mut self, lo: [Real; 3], hi: [Real; 3]) -> Point3<Real> {
        let x = self.uniform(lo[0], hi[0]);
        let y = self.uniform(lo[1], hi[1]);
        let z = self.uniform(lo[2], hi[2]);
        Point3::new(x, y, z)
    }

    /// Standard normal (Box–Muller, two draws per value).
    pub fn gaussian(&mut self) -> Real {
        let u = self.next().max(1e-300);
        let v = self.next();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}
