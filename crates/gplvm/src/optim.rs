//! Optimisers of the GPLVM objective: Hooke-Jeeves direct search (the paper's method, Hooke &
//! Jeeves 1961) and L-BFGS with a More-Thuente line search (argmin) on the analytic gradient.
//!
//! Both minimise a function of a flat parameter vector and count objective evaluations, so
//! they can be compared at equal cost.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;

use crate::error::{Error, Result};

/// Settings of the Hooke-Jeeves pattern search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HookeJeevesSettings {
    /// Initial step along every coordinate.
    pub initial_step: f64,
    /// Factor applied to the step when no exploratory move improves (0 < factor < 1).
    pub step_reduction: f64,
    /// Stop when the step falls below this.
    pub min_step: f64,
    /// Stop after this many objective evaluations.
    pub max_evaluations: usize,
}

impl Default for HookeJeevesSettings {
    fn default() -> Self {
        Self {
            initial_step: 0.1,
            step_reduction: 0.5,
            min_step: 1e-6,
            max_evaluations: 200_000,
        }
    }
}

/// Settings of L-BFGS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LbfgsSettings {
    /// Number of correction pairs kept. The GPLVM has N q parameters and each evaluation costs
    /// O(N^3), so a long memory is nearly free; on the default synthetic set (N q = 102) a
    /// memory of 100 needs 115 evaluations on raw data where 10 needs 744 (fit_bench example).
    pub memory: usize,
    /// Maximum number of iterations.
    pub max_iterations: u64,
    /// Stop when the gradient norm falls below this.
    pub gradient_tolerance: f64,
    /// Stop when the relative change of the objective falls below this.
    pub cost_tolerance: f64,
}

impl Default for LbfgsSettings {
    fn default() -> Self {
        Self {
            memory: 100,
            max_iterations: 2_000,
            gradient_tolerance: 1e-6,
            cost_tolerance: 1e-12,
        }
    }
}

/// Outcome of a minimisation.
#[derive(Debug, Clone, PartialEq)]
pub struct Minimum {
    /// Best parameters found.
    pub x: Vec<f64>,
    /// Objective value at `x`.
    pub value: f64,
    /// Iterations of the method (pattern moves or L-BFGS steps).
    pub iterations: u64,
    /// Objective evaluations (value-and-gradient evaluations for L-BFGS).
    pub evaluations: u64,
    /// Why the method stopped.
    pub stop_reason: String,
}

/// Minimises `f` by Hooke-Jeeves direct search from `x0`.
///
/// Exploratory moves try +step and -step along each coordinate in turn, keeping any
/// improvement; a successful exploration is followed by a pattern move `x + (x - x_previous)`
/// that is kept when its own exploration improves on the base point. When no move improves,
/// the step is reduced. Non-finite objective values count as no improvement.
pub fn hooke_jeeves(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    settings: &HookeJeevesSettings,
) -> Result<Minimum> {
    let s = *settings;
    if !(s.initial_step > 0.0 && s.step_reduction > 0.0 && s.step_reduction < 1.0) {
        return Err(Error::InvalidConfig {
            reason: format!(
                "Hooke-Jeeves needs initial_step > 0 and 0 < step_reduction < 1, got {s:?}"
            ),
        });
    }
    let evaluations = Cell::new(0u64);
    let mut eval = |x: &[f64]| {
        evaluations.set(evaluations.get() + 1);
        let v = f(x);
        if v.is_finite() { v } else { f64::INFINITY }
    };
    let mut base = x0.to_vec();
    let mut base_value = eval(&base);
    if !base_value.is_finite() {
        return Err(Error::Objective {
            reason: "the objective is not finite at the starting point".into(),
        });
    }
    let mut step = s.initial_step;
    let mut iterations = 0u64;

    // One sweep of exploratory moves around `point`; returns the improved point and value.
    fn explore(
        eval: &mut impl FnMut(&[f64]) -> f64,
        point: &[f64],
        value: f64,
        step: f64,
    ) -> (Vec<f64>, f64) {
        let mut x = point.to_vec();
        let mut best = value;
        for i in 0..x.len() {
            let orig = x[i];
            x[i] = orig + step;
            let up = eval(&x);
            if up < best {
                best = up;
                continue;
            }
            x[i] = orig - step;
            let down = eval(&x);
            if down < best {
                best = down;
                continue;
            }
            x[i] = orig;
        }
        (x, best)
    }

    let stop_reason = loop {
        if step < s.min_step {
            break format!("step {step:.3e} below {:.1e}", s.min_step);
        }
        if evaluations.get() as usize >= s.max_evaluations {
            break format!("reached {} evaluations", s.max_evaluations);
        }
        iterations += 1;
        let (mut x, mut value) = explore(&mut eval, &base, base_value, step);
        if value < base_value {
            // Pattern moves while they keep improving.
            loop {
                let pattern: Vec<f64> = x.iter().zip(&base).map(|(a, b)| 2.0 * a - b).collect();
                let pattern_value = eval(&pattern);
                let (px, pv) = explore(&mut eval, &pattern, pattern_value, step);
                base = x;
                base_value = value;
                if pv < base_value && (evaluations.get() as usize) < s.max_evaluations {
                    x = px;
                    value = pv;
                } else {
                    break;
                }
            }
        } else {
            step *= s.step_reduction;
        }
    };
    Ok(Minimum {
        x: base,
        value: base_value,
        iterations,
        evaluations: evaluations.get(),
        stop_reason,
    })
}

/// A cached evaluation: parameters, value, gradient.
type Evaluation = (Vec<f64>, f64, Vec<f64>);

/// The argmin problem wrapper: caches the last value-and-gradient evaluation, because argmin
/// asks for the cost and the gradient separately at the same point.
struct CachedProblem<F> {
    f: RefCell<F>,
    cache: RefCell<Option<Evaluation>>,
    evaluations: Rc<Cell<u64>>,
}

impl<F: FnMut(&[f64]) -> Result<(f64, Vec<f64>)>> CachedProblem<F> {
    fn eval(&self, x: &[f64]) -> Result<(f64, Vec<f64>)> {
        if let Some((cx, v, g)) = self.cache.borrow().as_ref() {
            if cx.as_slice() == x {
                return Ok((*v, g.clone()));
            }
        }
        self.evaluations.set(self.evaluations.get() + 1);
        let (v, g) = (self.f.borrow_mut())(x)?;
        *self.cache.borrow_mut() = Some((x.to_vec(), v, g.clone()));
        Ok((v, g))
    }
}

impl<F: FnMut(&[f64]) -> Result<(f64, Vec<f64>)>> CostFunction for CachedProblem<F> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Self::Param) -> std::result::Result<f64, argmin::core::Error> {
        Ok(self.eval(x)?.0)
    }
}

impl<F: FnMut(&[f64]) -> Result<(f64, Vec<f64>)>> Gradient for CachedProblem<F> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, x: &Self::Param) -> std::result::Result<Vec<f64>, argmin::core::Error> {
        Ok(self.eval(x)?.1)
    }
}

/// Minimises `f` (returning value and gradient) by L-BFGS from `x0`.
pub fn lbfgs(
    f: impl FnMut(&[f64]) -> Result<(f64, Vec<f64>)>,
    x0: &[f64],
    settings: &LbfgsSettings,
) -> Result<Minimum> {
    let evaluations = Rc::new(Cell::new(0u64));
    let problem = CachedProblem {
        f: RefCell::new(f),
        cache: RefCell::new(None),
        evaluations: Rc::clone(&evaluations),
    };
    let argmin_err = |e: argmin::core::Error| Error::Objective {
        reason: format!("L-BFGS: {e}"),
    };
    let linesearch = MoreThuenteLineSearch::new();
    let solver = LBFGS::new(linesearch, settings.memory.max(1))
        .with_tolerance_grad(settings.gradient_tolerance)
        .map_err(argmin_err)?
        .with_tolerance_cost(settings.cost_tolerance)
        .map_err(argmin_err)?;
    let result = Executor::new(problem, solver)
        .configure(|state| state.param(x0.to_vec()).max_iters(settings.max_iterations))
        .run()
        .map_err(argmin_err)?;
    let state = result.state();
    let x = state
        .get_best_param()
        .cloned()
        .unwrap_or_else(|| x0.to_vec());
    let value = state.get_best_cost();
    let iterations = state.get_iter();
    let stop_reason = format!("{}", state.get_termination_status());
    let evaluations = evaluations.get();
    Ok(Minimum {
        x,
        value,
        iterations,
        evaluations,
        stop_reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock function and its gradient.
    fn rosenbrock(x: &[f64]) -> (f64, Vec<f64>) {
        let (a, b) = (x[0], x[1]);
        let v = (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2);
        let g = vec![
            -2.0 * (1.0 - a) - 400.0 * a * (b - a * a),
            200.0 * (b - a * a),
        ];
        (v, g)
    }

    #[test]
    fn hooke_jeeves_finds_quadratic_minimum() {
        let f = |x: &[f64]| (x[0] - 1.5).powi(2) + 3.0 * (x[1] + 0.5).powi(2) + x[2].powi(2);
        let m = hooke_jeeves(f, &[0.0, 0.0, 1.0], &HookeJeevesSettings::default()).unwrap();
        assert!(
            (m.x[0] - 1.5).abs() < 1e-5 && (m.x[1] + 0.5).abs() < 1e-5,
            "{m:?}"
        );
        assert!(m.x[2].abs() < 1e-5 && m.value < 1e-9);
    }

    #[test]
    fn hooke_jeeves_on_rosenbrock() {
        let s = HookeJeevesSettings {
            min_step: 1e-9,
            ..Default::default()
        };
        let m = hooke_jeeves(|x| rosenbrock(x).0, &[-1.2, 1.0], &s).unwrap();
        assert!(
            (m.x[0] - 1.0).abs() < 1e-3 && (m.x[1] - 1.0).abs() < 2e-3,
            "{m:?}"
        );
    }

    #[test]
    fn lbfgs_on_rosenbrock_uses_few_evaluations() {
        let m = lbfgs(
            |x| Ok(rosenbrock(x)),
            &[-1.2, 1.0],
            &LbfgsSettings::default(),
        )
        .unwrap();
        assert!(
            (m.x[0] - 1.0).abs() < 1e-6 && (m.x[1] - 1.0).abs() < 1e-6,
            "{m:?}"
        );
        assert!(m.evaluations < 200, "{m:?}");
    }

    #[test]
    fn bad_settings_and_non_finite_start_are_errors() {
        let s = HookeJeevesSettings {
            step_reduction: 1.5,
            ..Default::default()
        };
        assert!(hooke_jeeves(|x| x[0], &[0.0], &s).is_err());
        let s = HookeJeevesSettings::default();
        assert!(hooke_jeeves(|_| f64::NAN, &[0.0], &s).is_err());
    }
}
