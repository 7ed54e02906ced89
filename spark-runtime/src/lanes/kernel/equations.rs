//! The kernel's side of the equations of a step (paper eq. 6.1), in lanes:
//! the starting guess, the stage points, the system's stage values lane by
//! lane, and the residual (`step::guess` and `step::equations`, operation
//! for operation).

// Stage and lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

use super::{Kernel, L};
use crate::step::{extrapolation_degree, NewtonOptions, StepPolynomial, EXTRAPOLATION, MAX_EXTRAPOLATION_DEGREE, PAST};
use crate::system::NonholonomicSystem;
use crate::tableau::{ConditionRows, Tableau};

impl<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> Kernel<N, M, S, D, W> {
    /// The extrapolated starting guess of every held lane
    /// (`Stepper::starting_guess` on a continuing step of equal size).
    #[inline(always)]
    pub(super) fn starting_guess(&mut self, opts: &NewtonOptions) {
        if let Some(poly) = self.step_polynomial {
            self.step_polynomial_guess(&poly);
            return;
        }
        let degree = |w: usize| extrapolation_degree(self.depth[w], opts.extrapolation_degree, self.rate[w].0);
        let end = S * (N + M);
        let first = (0..W).find(|&w| self.held[w]);
        let uniform = first
            .is_some_and(|f| (0..W).all(|w| !self.held[w] || (degree(w) == degree(f) && self.head[w] == self.head[f])));
        // The start velocity less the extrapolated previous ones (step k's
        // `v₀` is step k+1's `v₁`), added to every velocity block.
        let mut start = [[0.0; W]; N];
        // The rows of `z` that hold velocities, with their coordinate.
        let coordinate = |d: usize| if d < S * N { Some(d % N) } else { d.checked_sub(end) };
        if let (Some(f), true) = (first, uniform) {
            // Every held lane extrapolates alike: whole rows at once (the
            // lanes not held compute garbage nobody reads), each row's sum
            // and its start velocity in one pass, so a row is stored once.
            let (degree, head) = (degree(f), self.head[f]);
            // Each previous solution as an array of constant length, so the
            // row loops carry no bounds checks and vectorize across lanes.
            // Filled by a loop: `array::from_fn`'s closure stays a call here.
            let ring: &[[L<W>; D]] = self.past.as_chunks::<D>().0;
            let coefs = &EXTRAPOLATION[degree][..=degree];
            let mut latest: [&[L<W>; D]; MAX_EXTRAPOLATION_DEGREE + 1] = [&ring[0]; MAX_EXTRAPOLATION_DEGREE + 1];
            let mut previous = latest;
            for k in 0..=MAX_EXTRAPOLATION_DEGREE {
                latest[k] = &ring[(head + k) % PAST];
                previous[k] = &ring[(head + k + 1) % PAST];
            }
            // Row by row with one row of lanes in flight (a whole `N × W`
            // block in flight is split into scalars and not vectorized);
            // each entry sees the terms in the same order.
            for n in 0..N {
                let mut row = self.v[n];
                for (coef, before) in coefs.iter().zip(&previous) {
                    let before = before[end + n];
                    for w in 0..W {
                        row[w] -= *coef * before[w];
                    }
                }
                start[n] = row;
            }
            for d in 0..D {
                let mut z = [0.0; W];
                for (coef, past) in coefs.iter().zip(&latest) {
                    let past = past[d];
                    for w in 0..W {
                        z[w] += *coef * past[w];
                    }
                }
                if let Some(n) = coordinate(d) {
                    for w in 0..W {
                        z[w] += start[n][w];
                    }
                }
                self.z[d] = z;
            }
        } else {
            for w in (0..W).filter(|&w| self.held[w]) {
                let degree = degree(w);
                for n in 0..N {
                    start[n][w] = self.v[n][w];
                }
                for d in 0..D {
                    self.z[d][w] = 0.0;
                }
                for (k, coef) in EXTRAPOLATION[degree].iter().enumerate().take(degree + 1) {
                    let slot = (self.head[w] + k) % PAST;
                    for d in 0..D {
                        self.z[d][w] += *coef * self.past[slot * D + d][w];
                    }
                    let before = ((self.head[w] + k + 1) % PAST) * D + end;
                    for n in 0..N {
                        start[n][w] -= *coef * self.past[before + n][w];
                    }
                }
                for d in 0..D {
                    if let Some(n) = coordinate(d) {
                        self.z[d][w] += start[n][w];
                    }
                }
            }
        }
    }

    /// The starting guess of a continuing Gauss step, every held lane from
    /// its latest two solutions (`StepPolynomial::predict`, in its order of
    /// operations; the kernel's lanes hold at least two).
    #[inline(always)]
    fn step_polynomial_guess(&mut self, poly: &StepPolynomial<S>) {
        let end = S * (N + M);
        for w in (0..W).filter(|&w| self.held[w]) {
            let (last, before) = (self.head[w] * D, ((self.head[w] + 1) % PAST) * D);
            for i in 0..=S {
                let (from_start, from_stages, at) = if i < S {
                    (poly.stage_from_start[i], &poly.stage_from_stages[i], i * N)
                } else {
                    (poly.end_from_start, &poly.end_from_stages, end)
                };
                for n in 0..N {
                    let v0 = self.past[last + end + n][w];
                    let mut acc = from_start * (self.past[before + end + n][w] - v0);
                    for j in 0..S {
                        acc += from_stages[j] * (self.past[last + j * N + n][w] - v0);
                    }
                    self.z[at + n][w] = v0 + acc;
                }
            }
            for i in 0..S {
                for m in 0..M {
                    let mut acc = 0.0;
                    for j in 0..S {
                        acc += poly.multipliers[i][j] * self.past[last + S * N + j * M + m][w];
                    }
                    self.z[S * N + i * M + m][w] = acc;
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
                let c = h * weights[j];
                for w in 0..W {
                    d[w] += c * self.z[j * N + n][w];
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
    /// with the constraint Jacobians when `refresh` (the lean refresh), in
    /// one lane-form evaluation per point
    /// ([`NonholonomicSystem::stage_values_in_lanes`]; at the end point and
    /// the midpoint [`NonholonomicSystem::end_point_values_in_lanes`], the
    /// momentum and the constraint alone). The values of a lane
    /// that stopped iterating may be overwritten there: nothing reads them
    /// again (its step is committed from `z`, and the next step evaluates
    /// every held lane at its first iteration).
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
        for p in 0..points {
            let (tp, v_at) = match p {
                p if p < S => (t + tab.c[p] * h, p * N),
                p if p == S => (t + h, S * (N + M)),
                _ => (t + 0.5 * h, 0),
            };
            // The velocities straight from `z` (a copy of `N × W` values
            // would be a `memmove` call per point).
            let v: &[[f64; W]; N] = self.z[v_at..v_at + N].try_into().expect("N rows of z");
            let jacobians = if refresh { Some(&mut self.jacobians[p]) } else { None };
            if p < S {
                let psi: [[f64; W]; M] = std::array::from_fn(|m| self.z[S * N + p * M + m].map(|z| z * (1.0 / h)));
                sys.stage_values_in_lanes(tp, &self.points[p], v, &psi, iterating, &mut self.values[p], jacobians);
            } else {
                // The residual reads the momentum and the constraint alone
                // there (`Stepper::evaluate`'s end point).
                sys.end_point_values_in_lanes(tp, &self.points[p], v, iterating, &mut self.values[p], jacobians);
            }
        }
    }

    /// The residual of eq. (6.1) into `g` (`Stepper::residual`). It is not
    /// tested for finiteness here: the solve forms row `d` of the update
    /// from `g_d` itself (a product with the reciprocal mass or a pivot, a
    /// triangular substitution, or an inverse's row, never a skipped zero),
    /// and a NaN or an infinity stays non-finite through products and sums
    /// (`0·∞` is NaN). So the lane's update norm is not finite, and the lane
    /// goes back to its stepper, which meets the same residual and reports
    /// it (`a_residual_that_turns_nan_in_lanes_fails_as_alone`).
    #[inline(always)]
    pub(super) fn residual(&mut self, tab: &Tableau<S>) {
        let h = self.h;
        let put = |g: &mut [[f64; W]; D], d: usize, r: [f64; W]| {
            g[d] = r;
        };
        for i in 0..=S {
            let (hat, tilde) = if i < S { (&tab.a_hat[i], &tab.a_tilde[i]) } else { (&tab.b_hat, &tab.b_tilde) };
            for n in 0..N {
                let (momentum, p0) = (self.values[i].momentum[n], self.p0[n]);
                let mut r = [0.0; W];
                for w in 0..W {
                    r[w] = momentum[w] - p0[w];
                }
                for j in 0..S {
                    let (c, f) = (h * hat[j], self.values[j].force[n]);
                    for w in 0..W {
                        r[w] -= c * f[w];
                    }
                    let (c, f) = (h * tilde[j], self.values[j].constraint_force[n]);
                    for w in 0..W {
                        r[w] -= c * f[w];
                    }
                }
                put(&mut self.g, i * N + n, r);
            }
        }
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        let mut k = [0.0; W];
                        for j in 0..S {
                            let (c, con) = (tab.omega[r][j], self.values[j].constraint[m]);
                            for w in 0..W {
                                k[w] += c * con[w];
                            }
                        }
                        put(&mut self.g, base + r * M + m, k);
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        let row = if r == 0 { self.values[S + 1].constraint[m] } else { [0.0; W] };
                        put(&mut self.g, base + r * M + m, row);
                    }
                }
            }
            ConditionRows::EqualMultipliers => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        let (a, b) = (self.z[S * N + r * M + m], self.z[S * N + (r + 1) * M + m]);
                        put(&mut self.g, base + r * M + m, std::array::from_fn(|w| a[w] - b[w]));
                    }
                }
            }
        }
        for m in 0..M {
            put(&mut self.g, D - M + m, self.values[S].constraint[m]);
        }
    }
}
