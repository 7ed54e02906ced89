//! The kernel's side of the equations of a step (paper eq. 6.1), in lanes:
//! the starting guess, the stage points, the system's stage values lane by
//! lane, and the residual (`step::guess` and `step::equations`, operation
//! for operation).

// Stage and lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

use super::Kernel;
use crate::step::{NewtonOptions, EXTRAPOLATION, PAST};
use crate::system::{Matrix, NonholonomicSystem, StageValues, Vector};
use crate::tableau::{ConditionRows, Tableau};

impl<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> Kernel<N, M, S, D, W> {
    /// The extrapolated starting guess of every held lane
    /// (`Stepper::starting_guess` on a continuing step of equal size).
    #[inline(always)]
    pub(super) fn starting_guess(&mut self, opts: &NewtonOptions) {
        let degree = |w: usize| (self.depth[w] - 1).min(opts.extrapolation_degree.clamp(1, PAST - 1));
        let first = (0..W).find(|&w| self.held[w]);
        let uniform = first
            .is_some_and(|f| (0..W).all(|w| !self.held[w] || (degree(w) == degree(f) && self.head[w] == self.head[f])));
        if let (Some(f), true) = (first, uniform) {
            // Every held lane extrapolates alike: whole rows at once (the
            // lanes not held compute garbage nobody reads).
            let (degree, head) = (degree(f), self.head[f]);
            for d in 0..D {
                let mut z = [0.0; W];
                for (k, coef) in EXTRAPOLATION[degree - 1].iter().enumerate().take(degree + 1) {
                    let past = self.past[((head + k) % PAST) * D + d];
                    for w in 0..W {
                        z[w] += *coef * past[w];
                    }
                }
                self.z[d] = z;
            }
            return;
        }
        for w in 0..W {
            if !self.held[w] {
                continue;
            }
            let degree = degree(w);
            for d in 0..D {
                self.z[d][w] = 0.0;
            }
            for (k, coef) in EXTRAPOLATION[degree - 1].iter().enumerate().take(degree + 1) {
                let slot = (self.head[w] + k) % PAST;
                for d in 0..D {
                    self.z[d][w] += *coef * self.past[slot * D + d][w];
                }
            }
        }
    }

    /// `carry + Σ_j (h c_j) V_j` added to `q`, into point `p`
    /// (`equations::increment`).
    #[inline(always)]
    pub(super) fn point_from(&mut self, p: usize, weights: &[f64; S]) {
        let h = self.h;
        for n in 0..N {
            let mut d = self.carry[n];
            for j in 0..S {
                if weights[j] != 0.0 {
                    let c = h * weights[j];
                    for w in 0..W {
                        d[w] += c * self.z[j * N + n][w];
                    }
                }
            }
            let q = self.q[n];
            let mut point = [0.0; W];
            for w in 0..W {
                point[w] = q[w] + d[w];
            }
            self.points[p][n] = point;
        }
    }

    /// Positions of the stage points, the end point and the midpoint.
    #[inline(always)]
    pub(super) fn stage_points(&mut self, tab: &Tableau<S>) {
        for i in 0..S {
            self.point_from(i, &tab.a[i]);
        }
        self.point_from(S, &tab.b);
        if tab.conditions == ConditionRows::MidpointConstraint {
            let half = 0.5 * self.h;
            for n in 0..N {
                let (carry, q, v) = (self.carry[n], self.q[n], self.z[n]);
                let mut point = [0.0; W];
                for w in 0..W {
                    point[w] = q[w] + (carry[w] + half * v[w]);
                }
                self.points[S + 1][n] = point;
            }
        }
    }

    /// The system's stage values at every point of the iterating lanes,
    /// with the constraint Jacobians when `refresh` (the lean refresh).
    #[inline(always)]
    pub(super) fn evaluate<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        t: f64,
        iterating: &[bool; W],
        refresh: bool,
    ) {
        let h = self.h;
        let points = if tab.conditions == ConditionRows::MidpointConstraint { S + 2 } else { S + 1 };
        let mut kq = Matrix::<M, N>::zeros();
        let mut kv = Matrix::<M, N>::zeros();
        for w in 0..W {
            if !iterating[w] {
                continue;
            }
            for p in 0..points {
                let (tp, v_at) = match p {
                    p if p < S => (t + tab.c[p] * h, p * N),
                    p if p == S => (t + h, S * (N + M)),
                    _ => (t + 0.5 * h, 0),
                };
                let q = Vector::<N>::from_fn(|n, _| self.points[p][n][w]);
                let v = self.lane_vector::<N>(&self.z[..], v_at, w);
                let psi =
                    if p < S { Vector::<M>::from_fn(|m, _| self.z[S * N + p * M + m][w] / h) } else { Vector::zeros() };
                let vals = if refresh {
                    let mut vals = StageValues::zeros();
                    sys.stage_values_and_constraint_jacobians(tp, &q, &v, &psi, &mut vals, &mut kq, &mut kv);
                    for e in 0..M * N {
                        self.constraint_q[p * M * N + e][w] = kq.as_slice()[e];
                        self.constraint_v[p * M * N + e][w] = kv.as_slice()[e];
                    }
                    vals
                } else {
                    sys.stage_values(tp, &q, &v, &psi)
                };
                for n in 0..N {
                    self.momentum[p][n][w] = vals.momentum[n];
                    self.force[p][n][w] = vals.force[n];
                    self.constraint_force[p][n][w] = vals.constraint_force[n];
                }
                for m in 0..M {
                    self.constraint[p][m][w] = vals.constraint[m];
                }
            }
        }
    }

    /// The residual of eq. (6.1) into `g` (`Stepper::residual`).
    #[inline(always)]
    pub(super) fn residual(&mut self, tab: &Tableau<S>) {
        let h = self.h;
        for i in 0..=S {
            let (hat, tilde) = if i < S { (&tab.a_hat[i], &tab.a_tilde[i]) } else { (&tab.b_hat, &tab.b_tilde) };
            for n in 0..N {
                let (momentum, p0) = (self.momentum[i][n], self.p0[n]);
                let mut r = [0.0; W];
                for w in 0..W {
                    r[w] = momentum[w] - p0[w];
                }
                for j in 0..S {
                    if hat[j] != 0.0 {
                        let (c, f) = (h * hat[j], self.force[j][n]);
                        for w in 0..W {
                            r[w] -= c * f[w];
                        }
                    }
                    if tilde[j] != 0.0 {
                        let (c, f) = (h * tilde[j], self.constraint_force[j][n]);
                        for w in 0..W {
                            r[w] -= c * f[w];
                        }
                    }
                }
                self.g[i * N + n] = r;
            }
        }
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        let mut k = [0.0; W];
                        for j in 0..S {
                            let (c, con) = (tab.omega[r][j], self.constraint[j][m]);
                            for w in 0..W {
                                k[w] += c * con[w];
                            }
                        }
                        self.g[base + r * M + m] = k;
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        self.g[base + r * M + m] = if r == 0 { self.constraint[S + 1][m] } else { [0.0; W] };
                    }
                }
            }
            ConditionRows::EqualMultipliers => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        for w in 0..W {
                            self.g[base + r * M + m][w] =
                                self.z[S * N + r * M + m][w] - self.z[S * N + (r + 1) * M + m][w];
                        }
                    }
                }
            }
        }
        for m in 0..M {
            self.g[D - M + m] = self.constraint[S][m];
        }
    }
}
