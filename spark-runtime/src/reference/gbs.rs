//! The Gragg–Bulirsch–Stoer extrapolation solver (ODEX's order and
//! step-size control) behind [`integrate_at`](super::integrate_at).

use super::acceleration::{acceleration_with, Scratch};
use super::{ReferenceError, ReferenceOptions, ReferenceStats};
use crate::system::{NonholonomicSystem, Vector};

/// A point `(q, v)` of the first-order system, or its derivative `(q̇, v̇)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct State<const N: usize> {
    pub(super) q: Vector<N>,
    pub(super) v: Vector<N>,
}

impl<const N: usize> State<N> {
    fn axpy(&self, h: f64, d: &State<N>) -> State<N> {
        State { q: self.q + d.q * h, v: self.v + d.v * h }
    }
}

/// Safety factors of ODEX (Hairer–Wanner): step-size estimate
/// `H_j = H · 0.94 · (0.65/err_j)^{1/(2j−1)}`, bounded by `fac1^{1/(2j−1)}`.
const SAFE1: f64 = 0.65;
const SAFE2: f64 = 0.94;
const FAC1: f64 = 0.02;
const FAC2: f64 = 4.0;
/// Order-selection thresholds on the work per unit step (ODEX's FAC3, FAC4).
const WORK_DOWN: f64 = 0.9;
const WORK_UP: f64 = 0.9;

/// The solver's state between output times: the proposed step and order,
/// the extrapolation tableau and the statistics.
pub(super) struct Gbs<'a, S: ?Sized, const N: usize, const M: usize> {
    sys: &'a S,
    options: ReferenceOptions,
    /// Step sizes proposed for the next attempt (magnitude) and the target row.
    h: Option<f64>,
    k_target: usize,
    /// Cumulated work `A_j = 1 + Σ_{i≤j} n_i` (rhs evaluations to build row j).
    work: Vec<f64>,
    /// Extrapolation tableau, one entry per row (row j stores `T_{j,j}` after
    /// extrapolation; the previous row is kept for the next level).
    tableau: Vec<State<N>>,
    last_rejected: bool,
    pub(super) stats: ReferenceStats,
    /// Heap storage of the right-hand side's saddle solves.
    scratch: Scratch<N, M>,
}

impl<'a, S, const N: usize, const M: usize> Gbs<'a, S, N, M>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    pub(super) fn new(sys: &'a S, options: &ReferenceOptions) -> Self {
        let rows = options.max_rows;
        let mut work = vec![0.0; rows + 1];
        work[1] = (seq(1) + 1) as f64;
        for j in 2..=rows {
            work[j] = work[j - 1] + seq(j) as f64;
        }
        let k_target = ((-(options.rtol.max(1e-16)).log10() * 0.6 + 1.5) as usize).clamp(2, rows - 1);
        Self {
            sys,
            options: options.clone(),
            h: options.initial_step,
            k_target,
            work,
            tableau: vec![State { q: Vector::zeros(), v: Vector::zeros() }; rows + 1],
            last_rejected: false,
            stats: ReferenceStats::default(),
            scratch: Scratch::new(),
        }
    }

    fn rhs(&mut self, t: f64, y: &State<N>) -> Result<State<N>, ReferenceError> {
        self.stats.rhs_evaluations += 1;
        let (vdot, _) = acceleration_with::<S, N, M>(self.sys, t, &y.q, &y.v, &mut self.scratch)?;
        Ok(State { q: y.v, v: vdot })
    }

    /// Scaled maximum norm of `d` with weights from `y0`, `y1` (the maximum
    /// rather than ODEX's RMS norm: the reference must bound every component).
    fn error_norm(&self, d: &State<N>, y0: &State<N>, y1: &State<N>) -> f64 {
        let o = &self.options;
        let mut worst: f64 = 0.0;
        for i in 0..N {
            let sq = o.atol + o.rtol * y0.q[i].abs().max(y1.q[i].abs());
            let sv = o.atol + o.rtol * y0.v[i].abs().max(y1.v[i].abs());
            worst = worst.max((d.q[i] / sq).abs()).max((d.v[i] / sv).abs());
        }
        worst
    }

    /// A first step from the scales of the state and its derivative
    /// (Hairer–Wanner's heuristic `0.01‖y‖/‖f‖`, capped by the interval);
    /// the controller corrects it within a few steps.
    fn initial_step(y: &State<N>, f0: &State<N>, span: f64) -> f64 {
        let rms = |s: &State<N>| ((s.q.norm_squared() + s.v.norm_squared()) / (2 * N).max(1) as f64).sqrt();
        let (d0, d1) = (rms(y), rms(f0));
        let h = if d0 < 1e-5 || d1 < 1e-5 { 1e-3 } else { 0.01 * d0 / d1 };
        h.min(span.abs())
    }

    /// Gragg's modified midpoint rule with `n` substeps over `[t, t + h]`,
    /// returning the increment `z_n − y0`. Working with increments keeps the
    /// rounding errors proportional to the increment rather than to `|y0|`,
    /// which matters once the extrapolation amplifies them.
    fn midpoint(&mut self, t: f64, y0: &State<N>, f0: &State<N>, h: f64, n: usize) -> Result<State<N>, ReferenceError> {
        let hs = h / n as f64;
        let zero = State { q: Vector::zeros(), v: Vector::zeros() };
        let mut d_prev = zero;
        let mut d = zero.axpy(hs, f0);
        for i in 1..n {
            let z = State { q: y0.q + d.q, v: y0.v + d.v };
            let f = self.rhs(t + i as f64 * hs, &z)?;
            let d_next = d_prev.axpy(2.0 * hs, &f);
            d_prev = d;
            d = d_next;
        }
        Ok(d)
    }

    /// The order (tableau row) ODEX proposes after a step accepted at row
    /// `k` with target `kc`, from the work per unit step `w` of the rows.
    fn next_order(&self, k: usize, kc: usize, w: &[f64]) -> usize {
        let rows = self.options.max_rows;
        let mut kopt;
        if k == 2 {
            kopt = 3.min(rows - 1);
            if self.last_rejected {
                kopt = 2;
            }
        } else if k <= kc {
            kopt = k;
            if w[k - 1] < WORK_DOWN * w[k] {
                kopt = k - 1;
            }
            if w[k] < WORK_UP * w[k - 1] {
                kopt = (k + 1).min(rows - 1);
            }
        } else {
            kopt = k - 1;
            if k > 3 && w[k - 2] < WORK_DOWN * w[k - 1] {
                kopt = k - 2;
            }
            if w[k] < WORK_UP * w[kopt] {
                kopt = k.min(rows - 1);
            }
        }
        kopt
    }

    /// Advances from `(t, y)` to exactly `t_end`.
    pub(super) fn advance(&mut self, mut t: f64, mut y: State<N>, t_end: f64) -> Result<State<N>, ReferenceError> {
        let dir = (t_end - t).signum();
        let max_step = self.options.max_step.unwrap_or(f64::INFINITY);
        let mut f0 = self.rhs(t, &y)?;
        let mut h_mag = match self.h {
            Some(h) => h,
            None => Self::initial_step(&y, &f0, t_end - t),
        }
        .min(max_step);
        let rows = self.options.max_rows;
        let mut err = vec![0.0; rows + 1];
        let mut h_est = vec![0.0; rows + 1];
        let mut w = vec![0.0; rows + 1];
        loop {
            let remaining = (t_end - t) * dir;
            if remaining <= 0.0 {
                return Ok(y);
            }
            let last = h_mag >= remaining * (1.0 - 1e-12);
            let h = if last { remaining * dir } else { h_mag * dir };
            if h.abs() <= 4.0 * f64::EPSILON * t.abs().max(1.0) {
                return Err(ReferenceError::StepSizeTooSmall { t, h: h.abs() });
            }
            if self.stats.accepted_steps + self.stats.rejected_steps >= self.options.max_steps {
                return Err(ReferenceError::TooManySteps {
                    t,
                    steps: self.stats.accepted_steps + self.stats.rejected_steps,
                });
            }
            let kc = self.k_target;
            let mut outcome: Option<Result<usize, usize>> = None;
            for j in 1..=(kc + 1).min(rows) {
                let t1 = self.midpoint(t, &y, &f0, h, seq(j))?;
                // Aitken–Neville in h²: tableau[k] holds T_{j-1,k} on entry and
                // T_{j,k} on exit, k = 1..=j.
                let mut cur = t1;
                for k in 1..j {
                    let old = self.tableau[k];
                    self.tableau[k] = cur;
                    let ratio = (seq(j) as f64 / seq(j - k) as f64).powi(2) - 1.0;
                    let d = State { q: cur.q - old.q, v: cur.v - old.v };
                    cur = cur.axpy(1.0 / ratio, &d);
                }
                self.tableau[j] = cur;
                if j >= 2 {
                    let lower = self.tableau[j - 1];
                    let d = State { q: cur.q - lower.q, v: cur.v - lower.v };
                    let y1 = State { q: y.q + cur.q, v: y.v + cur.v };
                    err[j] = self.error_norm(&d, &y, &y1);
                    if !err[j].is_finite() {
                        err[j] = 1e300;
                    }
                    let expo = 1.0 / (2 * j - 1) as f64;
                    let facmin = FAC1.powf(expo);
                    let fac = (FAC2 / facmin).min(facmin.max((err[j] / SAFE1).powf(expo) / SAFE2));
                    h_est[j] = (h.abs() / fac).min(max_step);
                    w[j] = self.work[j] / h_est[j];
                }
                if j < 2 {
                    continue;
                }
                let n1 = seq(1) as f64;
                if j + 1 == kc {
                    if err[j] <= 1.0 {
                        outcome = Some(Ok(j));
                        break;
                    }
                    let bound = (seq(kc + 1) as f64 * seq(kc) as f64 / (n1 * n1)).powi(2);
                    if err[j] > bound {
                        outcome = Some(Err(j));
                        break;
                    }
                } else if j == kc {
                    if err[j] <= 1.0 {
                        outcome = Some(Ok(j));
                        break;
                    }
                    if err[j] > (seq(kc + 1) as f64 / n1).powi(2) {
                        outcome = Some(Err(j));
                        break;
                    }
                } else if j == kc + 1 {
                    outcome = Some(if err[j] <= 1.0 { Ok(j) } else { Err(j) });
                    break;
                }
            }
            let outcome = outcome.unwrap_or(Err(rows.min(kc + 1)));
            match outcome {
                Ok(k) => {
                    self.stats.accepted_steps += 1;
                    y = State { q: y.q + self.tableau[k].q, v: y.v + self.tableau[k].v };
                    t = if last { t_end } else { t + h };
                    // The error estimate measures increments, which stay
                    // finite when the state itself overflows.
                    if !y.q.iter().chain(y.v.iter()).all(|x| x.is_finite()) {
                        return Err(ReferenceError::NonFiniteState { t });
                    }
                    let mut kopt = self.next_order(k, kc, &w);
                    let h_new = if self.last_rejected {
                        kopt = kopt.min(k);
                        h.abs().min(h_est[kopt])
                    } else if kopt <= k {
                        h_est[kopt]
                    } else if k < kc && w[k] < WORK_UP * w[k - 1] {
                        h_est[k] * self.work[kopt + 1] / self.work[k]
                    } else {
                        h_est[k] * self.work[kopt] / self.work[k]
                    };
                    self.k_target = kopt.max(2);
                    self.last_rejected = false;
                    // A step shortened to land on t_end does not cut the
                    // proposal for the next interval.
                    let h_new = if last { h_new.max(h_mag.min(h_new * 4.0)) } else { h_new };
                    h_mag = h_new.min(max_step);
                    self.h = Some(h_mag);
                    if t != t_end {
                        f0 = self.rhs(t, &y)?;
                    }
                }
                Err(k) => {
                    self.stats.rejected_steps += 1;
                    let mut kk = k.min(kc).min(rows - 1).max(2);
                    if kk > 2 && w[kk - 1] < WORK_DOWN * w[kk] {
                        kk -= 1;
                    }
                    self.k_target = kk;
                    h_mag = h_est[kk].min(h.abs() * 0.5).min(max_step);
                    self.last_rejected = true;
                }
            }
        }
    }
}

/// Step-number sequence `n_j = 2j` (Deuflhard's harmonic sequence doubled),
/// the sequence of ODEX.
fn seq(j: usize) -> usize {
    2 * j
}
