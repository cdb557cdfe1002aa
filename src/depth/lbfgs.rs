//! A small limited-memory BFGS minimiser (Nocedal & Wright, *Numerical Optimization*,
//! Algorithm 7.4/7.5) with a backtracking Armijo line search, for smooth objectives of a few
//! dozen variables.

use crate::Real;

/// Pairs of steps and gradient changes kept.
const MEMORY: usize = 8;

/// Minimises `objective` from `x` (updated in place) and returns the final value.
///
/// `objective(x, gradient)` returns `f(x)` and writes `∇f(x)`. `first_step` scales the first
/// search direction (`−first_step · ∇f`); later ones take BFGS's own scaling. Stops when the
/// gradient's largest entry has fallen to `gradient_tolerance` times its value at the start,
/// when an iteration lowers `f` by less than a relative 1e-15, when the line search fails, or
/// after `max_iterations`.
pub(crate) fn minimize(
    mut objective: impl FnMut(&[Real], &mut [Real]) -> Real,
    x: &mut [Real],
    first_step: Real,
    gradient_tolerance: Real,
    max_iterations: usize,
) -> Real {
    let n = x.len();
    let mut gradient = vec![0.0; n];
    let mut value = objective(x, &mut gradient);
    let gradient_tolerance = gradient_tolerance * gradient.iter().fold(0.0, |m: Real, g| m.max(g.abs()));
    let mut steps: Vec<(Vec<Real>, Vec<Real>, Real)> = Vec::with_capacity(MEMORY); // (s, y, 1/yᵀs)
    let mut direction = vec![0.0; n];
    let mut trial = vec![0.0; n];
    let mut trial_gradient = vec![0.0; n];
    let mut alpha = [0.0; MEMORY];
    for _ in 0..max_iterations {
        if gradient.iter().all(|g| g.abs() <= gradient_tolerance) {
            break;
        }
        // Two-loop recursion: direction = −H ∇f.
        direction.copy_from_slice(&gradient);
        for (k, (s, y, rho)) in steps.iter().enumerate().rev() {
            alpha[k] = rho * dot(s, &direction);
            axpy(-alpha[k], y, &mut direction);
        }
        let scale = match steps.last() {
            Some((s, y, _)) => dot(s, y) / dot(y, y),
            None => first_step,
        };
        direction.iter_mut().for_each(|d| *d *= scale);
        for (k, (s, y, rho)) in steps.iter().enumerate() {
            let beta = rho * dot(y, &direction);
            axpy(alpha[k] - beta, s, &mut direction);
        }
        direction.iter_mut().for_each(|d| *d = -*d);
        let mut slope = dot(&gradient, &direction);
        // `is_nan` too: a NaN slope is no descent direction either.
        if slope >= 0.0 || slope.is_nan() {
            // Not a descent direction (rounding in the memory): restart from steepest descent.
            steps.clear();
            for (d, g) in direction.iter_mut().zip(&gradient) {
                *d = -first_step * g;
            }
            slope = dot(&gradient, &direction);
            if slope >= 0.0 || slope.is_nan() {
                break;
            }
        }
        // Backtracking Armijo search.
        let mut step = 1.0;
        let mut accepted = None;
        for _ in 0..60 {
            for ((t, xi), d) in trial.iter_mut().zip(x.iter()).zip(&direction) {
                *t = xi + step * d;
            }
            let trial_value = objective(&trial, &mut trial_gradient);
            if trial_value.is_finite() && trial_value <= value + 1e-4 * step * slope {
                accepted = Some(trial_value);
                break;
            }
            step *= 0.5;
        }
        let Some(new_value) = accepted else { break };
        let s: Vec<Real> = trial.iter().zip(x.iter()).map(|(t, xi)| t - xi).collect();
        let y: Vec<Real> = trial_gradient.iter().zip(&gradient).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        x.copy_from_slice(&trial);
        gradient.copy_from_slice(&trial_gradient);
        let decrease = value - new_value;
        value = new_value;
        if sy > 1e-12 * dot(&s, &s).sqrt() * dot(&y, &y).sqrt() {
            if steps.len() == MEMORY {
                steps.remove(0);
            }
            steps.push((s, y, 1.0 / sy));
        }
        if decrease <= 1e-15 * value.abs() {
            break;
        }
    }
    value
}

fn dot(a: &[Real], b: &[Real]) -> Real {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn axpy(a: Real, x: &[Real], y: &mut [Real]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

#[cfg(test)]
mod tests {
    use super::minimize;

    #[test]
    fn finds_the_minimum_of_the_rosenbrock_function() {
        let mut x = [-1.2, 1.0];
        let value = minimize(
            |x, g| {
                let (a, b) = (1.0 - x[0], x[1] - x[0] * x[0]);
                g[0] = -2.0 * a - 400.0 * x[0] * b;
                g[1] = 200.0 * b;
                a * a + 100.0 * b * b
            },
            &mut x,
            1e-3,
            1e-12,
            500,
        );
        assert!(value < 1e-16, "f = {value}");
        assert!(
            (x[0] - 1.0).abs() < 1e-7 && (x[1] - 1.0).abs() < 1e-7,
            "x = {x:?}"
        );
    }

    #[test]
    fn solves_an_ill_conditioned_quadratic() {
        // f = Σ k (xₖ − k)², condition number 30.
        let mut x = [0.0; 30];
        minimize(
            |x, g| {
                let mut f = 0.0;
                for k in 0..30 {
                    let d = x[k] - k as f64;
                    f += (k + 1) as f64 * d * d;
                    g[k] = 2.0 * (k + 1) as f64 * d;
                }
                f
            },
            &mut x,
            0.01,
            1e-12,
            500,
        );
        for (k, xk) in x.iter().enumerate() {
            assert!((xk - k as f64).abs() < 1e-9, "x[{k}] = {xk}");
        }
    }
}
