//! The homotopy in the step size of a step that Newton solves from
//! none of its guesses: the step's equations are solved at fractions `θh`
//! of the step, `θ` rising from 0 to 1, each solve starting from a
//! prediction along the solutions found so far.
//!
//! At `h = 0` the step's equations have the root `V_i = v₀, μ_i = 0, v₁ =
//! v₀` (no motion, no impulse), and for small `h` the root that a
//! consistent method converges along is the one connected to it. Under
//! strong velocity-dependent forces (`h·‖∂f/∂v‖ ≫ 1`) the cold guess
//! `V_i = v₀ + c_i h a₀`, which moves along that root's tangent at `h = 0`,
//! can lie beyond Newton's reach of the root at the full `h`; the homotopy
//! follows the same branch in steps short enough for Newton, with a test
//! that each solution lies where the branch was predicted, so the root it
//! returns is that branch's rather than another root of the equations that
//! a guess far from the branch happens to reach. A branch that turns back or ends before
//! `θ = 1` (`h` beyond what the method can take there) leaves the step
//! failed with the error of the solve at the full step.

use crate::error::StepError;
use crate::system::{NonholonomicSystem, Vector};
use crate::{State, Stepper};

/// Sub-solves a homotopy makes at most, successful or not.
const MAX_SOLVES: usize = 32;

/// The smallest advance of `θ` a homotopy tries: a branch that needs
/// finer steps than `1/1024` of the step is treated as ending there.
const SMALLEST_ADVANCE: f64 = 1.0 / 1024.0;

/// A homotopy in progress.
pub(super) struct Homotopy<const D: usize> {
    /// The error of the solve at the full step, returned when the
    /// homotopy ends short of it.
    error: StepError,
    /// The largest fraction solved and its solution.
    solved: (f64, Vector<D>),
    /// The branch's slope `dz/dθ` estimated there.
    slope: Vector<D>,
    /// The fraction being solved.
    trying: f64,
    /// Sub-solves made.
    solves: usize,
}

impl<const D: usize> Homotopy<D> {
    /// A homotopy from the root `origin` of the equations at `h = 0`
    /// along the cold guess `cold` at the full step, which is `origin`
    /// plus the branch's tangent there; `error` is the full step's failure.
    pub(super) fn new(origin: Vector<D>, cold: &Vector<D>, error: StepError) -> Self {
        let slope = cold - origin;
        Homotopy { error, solved: (0.0, origin), slope, trying: 0.5, solves: 0 }
    }

    /// The fraction of the step to solve next.
    pub(super) fn fraction(&self) -> f64 {
        self.trying
    }

    /// The guess of the solve at [`fraction`](Self::fraction): the last
    /// solution moved along the branch's slope.
    pub(super) fn guess(&self) -> Vector<D> {
        self.solved.1 + (self.trying - self.solved.0) * self.slope
    }

    /// The solve at [`fraction`](Self::fraction) converged to `z`: whether
    /// `z` is kept as the branch's next point. The first solution is kept:
    /// its guess is the cold guess, the tangent of the velocities at
    /// `h = 0` (not always of the multipliers: for Lobatto IIIA-B-D `μ_i`
    /// starts off it). Later guesses move along the secant of the last two
    /// points, and a solution is kept when Newton moved from its guess by
    /// at most half the distance the guess moved along the branch. One
    /// farther from the prediction may lie on another branch, or the
    /// secant is poor where the branch curves (under a cubic drag it bends
    /// within `h·‖∂f/∂v‖ ≈ 1`): the advance is halved and its guess moves
    /// toward `z`, so a `z` on the branch is met again closely and kept. A
    /// kept solution puts the next fraction twice as far on, at most at
    /// the full step.
    pub(super) fn advance(&mut self, z: &Vector<D>) -> bool {
        let guess = self.guess();
        let (from, ref at) = self.solved;
        let advance = self.trying - from;
        let correction = (z - guess).amax();
        // A NaN or infinite distance is never kept.
        if !correction.is_finite() {
            return false;
        }
        let travel = (guess - at).amax();
        self.slope = (z - at) / advance;
        if from > 0.0 && correction > 0.5 * travel + 64.0 * f64::EPSILON * z.amax() {
            return false;
        }
        self.solves += 1;
        self.solved = (self.trying, *z);
        self.trying = (self.trying + 2.0 * advance).min(1.0);
        true
    }

    /// Whether the full step is solved.
    pub(super) fn reached(&self) -> bool {
        self.solved.0 == 1.0
    }

    /// The solve at [`fraction`](Self::fraction) failed: the next fraction
    /// lies half as far on, or the homotopy ends (`false`).
    pub(super) fn retreat(&mut self) -> bool {
        self.solves += 1;
        let advance = 0.5 * (self.trying - self.solved.0);
        if advance < SMALLEST_ADVANCE || self.solves >= MAX_SOLVES {
            return false;
        }
        self.trying = self.solved.0 + advance;
        true
    }

    /// The error of the full step, returned when the homotopy ends
    /// short of it.
    pub(super) fn into_error(self) -> StepError {
        self.error
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// After Newton failed with `error` from the cold guess (`path` empty)
    /// or at a fraction of the step (`path` running): the step size and the
    /// guess of the next solve, or the full step's error when the
    /// homotopy ends. Out of line and cold: only steps that fail from
    /// every guess get here.
    #[cold]
    #[inline(never)]
    pub(super) fn homotopy_after_failure(
        &mut self,
        path: &mut Option<Box<Homotopy<D>>>,
        state: &State<N>,
        h: f64,
        error: StepError,
    ) -> Result<(f64, Vector<D>), StepError> {
        let running = match path.take() {
            // Bad input fails the same way at every step size.
            None if !error.is_curable() => return Err(error),
            None => {
                let cold = self.cold_guess(state, h).z;
                let mut origin = Vector::<D>::zeros();
                for at in (0..S).map(|i| i * N).chain([S * (N + M)]) {
                    origin.fixed_rows_mut::<N>(at).copy_from(&state.v);
                }
                Box::new(Homotopy::new(origin, &cold, error))
            }
            Some(mut running) => {
                if !running.retreat() {
                    return Err(self.end_homotopy(*running));
                }
                running
            }
        };
        let next = (running.fraction() * h, running.guess());
        *path = Some(running);
        Ok(next)
    }

    /// After Newton solved a step of the homotopy to `z`: the step size and
    /// the guess of the next solve, `None` when `z` solves the full step,
    /// or the full step's error when the homotopy ends. Out of line and
    /// cold, as [`homotopy_after_failure`](Self::homotopy_after_failure).
    #[cold]
    #[inline(never)]
    pub(super) fn homotopy_after_solve(
        &mut self,
        path: &mut Option<Box<Homotopy<D>>>,
        h: f64,
        z: &Vector<D>,
    ) -> Result<Option<(f64, Vector<D>)>, StepError> {
        let Some(running) = path else { return Ok(None) };
        if running.advance(z) {
            if running.reached() {
                return Ok(None);
            }
        } else if !running.retreat() {
            return match path.take() {
                Some(ended) => Err(self.end_homotopy(*ended)),
                None => Ok(None),
            };
        }
        Ok(Some((running.fraction() * h, running.guess())))
    }

    /// The full step's error of a homotopy that ends short of it, with the
    /// stepper's last history set to that error's, the solve it reports.
    fn end_homotopy(&mut self, ended: Homotopy<D>) -> StepError {
        let error = ended.into_error();
        if let Some(history) = error.history() {
            self.history = *history;
        }
        error
    }
}
