//! Dense output: a continuous extension of one accepted SPARK step, so that
//! the solution can be sampled at any `t` inside a step without changing the
//! step size.
//!
//! A step from `(t₀, q₀, v₀)` of size `h` with stage velocities `V_j` at the
//! nodes `c_j` defines, for `θ = (t − t₀)/h ∈ [0, 1]`:
//!
//! - positions by the collocation-type polynomial of degree `s`
//!   `q(θ) = q₀ + h Σ_j β_j(θ) V_j`, `β_j(θ) = ∫₀^θ ℓ_j`, with `ℓ_j` the
//!   Lagrange basis on the nodes `c`. Its derivative in `t` is
//!   `Σ_j ℓ_j(θ) V_j`, and `q(1) = q₁` because the weights `b_j = ∫₀¹ ℓ_j` of
//!   every family here are the interpolatory quadrature weights of its nodes;
//! - velocities by the polynomial through `(0, v₀)`, the stage velocities at
//!   the nodes strictly inside `(0, 1)`, and `(1, v₁)`: degree `s + 1` for
//!   Gauss, `s − 1` for Lobatto, `1` for the symplectic Euler methods. The
//!   stage velocities at the end nodes of Lobatto methods are replaced by
//!   `v₀` and `v₁`, so the interpolant is continuous from step to step.
//!
//! At `θ = 0` and `θ = 1` the step's own states are returned bit for bit, so
//! samples and event locations at grid points agree with the grid. The
//! interpolants use only what the step computed: evaluating them costs
//! `O(s²)` flops plus `O(s·n)` for the combination, and nothing is computed
//! for a run that does not sample between grid points.

use crate::step::{State, StepResult};
use crate::system::Vector;
use crate::tableau::Tableau;

/// Where the value at one node of the velocity interpolant comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    Start,
    Stage(usize),
    End,
}

/// The coefficients of the interpolants of one tableau (computed once per
/// stepper; `O(s²)` numbers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DenseBasis<const S: usize> {
    /// `β_j(θ) = Σ_k beta[j][k] θ^(k+1)`.
    beta: [[f64; S]; S],
    /// `ℓ_j(θ) = Σ_k ell[j][k] θ^k`.
    ell: [[f64; S]; S],
    /// The velocity interpolant's nodes between its ends `0` and `1`: at
    /// most `S` of them, so any stage count fits (a tableau built by hand
    /// may have more stages than the checked-in tables).
    nodes: Nodes<S>,
    /// `1/Π_{m≠i}(x_i − x_m)` of the nodes `0` and `1`.
    end_denominators: [f64; 2],
    /// Number of nodes, both ends included.
    len: usize,
}

/// The nodes of the velocity interpolant between its two ends.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Nodes<const S: usize> {
    /// The stage nodes strictly inside `(0, 1)` (`len − 2` of them) and
    /// the stages they come from.
    interior: [f64; S],
    stage: [usize; S],
    /// Their `1/Π_{m≠i}(x_i − x_m)`.
    denominators: [f64; S],
}

impl<const S: usize> DenseBasis<S> {
    /// Node `i` of the velocity interpolant (`0 ≤ i < len`).
    fn node(&self, i: usize) -> f64 {
        match i {
            0 => 0.0,
            i if i + 1 == self.len => 1.0,
            i => self.nodes.interior[i - 1],
        }
    }

    /// Where node `i`'s value comes from, and its `1/Π_{m≠i}(x_i − x_m)`.
    fn source(&self, i: usize) -> (Source, f64) {
        match i {
            0 => (Source::Start, self.end_denominators[0]),
            i if i + 1 == self.len => (Source::End, self.end_denominators[1]),
            i => (Source::Stage(self.nodes.stage[i - 1]), self.nodes.denominators[i - 1]),
        }
    }
}

impl<const S: usize> DenseBasis<S> {
    /// The interpolation coefficients of `tableau`'s nodes.
    pub fn new(tableau: &Tableau<S>) -> Self {
        let c = tableau.c;
        let mut ell = [[0.0; S]; S];
        let mut beta = [[0.0; S]; S];
        for j in 0..S {
            // Expand Π_{m≠j} (θ − c_m)/(c_j − c_m) into monomials.
            let mut poly = [0.0; S];
            poly[0] = 1.0;
            let mut degree = 0;
            for (m, &cm) in c.iter().enumerate() {
                if m == j {
                    continue;
                }
                let scale = 1.0 / (c[j] - cm);
                for k in (0..=degree + 1).rev() {
                    let shifted = if k > 0 { poly[k - 1] } else { 0.0 };
                    let here = if k <= degree { poly[k] } else { 0.0 };
                    poly[k] = (shifted - cm * here) * scale;
                }
                degree += 1;
            }
            ell[j] = poly;
            for k in 0..S {
                beta[j][k] = poly[k] / (k + 1) as f64;
            }
        }
        let mut nodes = Nodes { interior: [0.0; S], stage: [0; S], denominators: [0.0; S] };
        let mut inside = 0;
        for (j, &cj) in c.iter().enumerate() {
            if cj > 0.0 && cj < 1.0 {
                nodes.interior[inside] = cj;
                nodes.stage[inside] = j;
                inside += 1;
            }
        }
        let mut basis = DenseBasis { beta, ell, nodes, end_denominators: [0.0; 2], len: inside + 2 };
        for i in 0..basis.len {
            let mut p = 1.0;
            for m in 0..basis.len {
                if m != i {
                    p *= basis.node(i) - basis.node(m);
                }
            }
            match i {
                0 => basis.end_denominators[0] = 1.0 / p,
                i if i + 1 == basis.len => basis.end_denominators[1] = 1.0 / p,
                i => basis.nodes.denominators[i - 1] = 1.0 / p,
            }
        }
        basis
    }

    /// Polynomial degree of the position interpolant (`s`).
    pub const fn position_degree(&self) -> usize {
        S
    }

    /// Polynomial degree of the velocity interpolant.
    pub const fn velocity_degree(&self) -> usize {
        self.len - 1
    }
}

/// One accepted step with what its continuous extension needs.
#[derive(Clone, Copy, Debug)]
pub struct DenseStep<'a, const N: usize, const S: usize> {
    /// The state at the start of the step.
    pub start: State<N>,
    /// The state at the end of the interval the extension covers: the end
    /// of the step, or the state at a terminal event that cuts the step
    /// short (see [`until`](Self::until)).
    pub end: State<N>,
    /// The step size the stage values belong to.
    pub h: f64,
    /// Stage velocities `V_j`.
    pub stage_velocities: [Vector<N>; S],
    basis: &'a DenseBasis<S>,
    /// The end of the whole step: the interpolant's `θ = 1` and its end
    /// velocity, whatever part of the step [`end`](Self::end) covers.
    step_end: State<N>,
}

/// The interpolated state and its time derivative at one `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DenseValue<const N: usize> {
    /// The state at `t`.
    pub state: State<N>,
    /// `dq/dt` of the interpolant.
    pub q_dot: Vector<N>,
    /// `dv/dt` of the interpolant.
    pub v_dot: Vector<N>,
}

impl<'a, const N: usize, const S: usize> DenseStep<'a, N, S> {
    /// The extension of the step from `start` to `end` of size `h` with the
    /// stage velocities of `result`.
    pub fn new<const M: usize>(
        basis: &'a DenseBasis<S>,
        start: &State<N>,
        end: &State<N>,
        h: f64,
        result: &StepResult<N, M, S>,
    ) -> Self {
        DenseStep { start: *start, end: *end, h, stage_velocities: result.stage_velocities, basis, step_end: *end }
    }

    /// The same extension restricted to `[t₀, t]` (`t` inside the step): its
    /// [`end`](Self::end) becomes the interpolated state at `t`, the
    /// polynomials stay those of the whole step.
    pub fn until(&self, t: f64) -> Self {
        DenseStep { end: self.state_at(t), ..*self }
    }

    /// Whether `t` lies in the closed interval between the start and the
    /// [`end`](Self::end) of the covered interval.
    pub fn contains(&self, t: f64) -> bool {
        let (a, b) = (self.start.t, self.end.t);
        (a.min(b)..=a.max(b)).contains(&t)
    }

    /// The normalized time `θ = (t − t₀)/(t₁ − t₀)`, `t₁` the end of the
    /// whole step.
    pub fn theta(&self, t: f64) -> f64 {
        (t - self.start.t) / (self.step_end.t - self.start.t)
    }

    /// The state at `t` (inside the step; outside it the polynomials are
    /// extrapolated). The step's own states are returned at its ends.
    pub fn state_at(&self, t: f64) -> State<N> {
        if t == self.start.t {
            return self.start;
        }
        if t == self.end.t {
            return self.end;
        }
        if t == self.step_end.t {
            return self.step_end;
        }
        let theta = self.theta(t);
        let (q, _) = self.position(theta);
        let (v, _) = self.velocity(theta, false);
        State { t, q, v }
    }

    /// The state at `t` with the time derivatives of the interpolants.
    pub fn value_at(&self, t: f64) -> DenseValue<N> {
        let theta = self.theta(t);
        let (q, q_dot) = self.position(theta);
        let (v, dv) = self.velocity(theta, true);
        let state = if t == self.start.t {
            self.start
        } else if t == self.end.t {
            self.end
        } else if t == self.step_end.t {
            self.step_end
        } else {
            State { t, q, v }
        };
        DenseValue { state, q_dot, v_dot: dv / self.h }
    }

    /// `q(θ)` and `dq/dt(θ)`.
    fn position(&self, theta: f64) -> (Vector<N>, Vector<N>) {
        let b = self.basis;
        let mut q = self.start.q;
        let mut q_dot = Vector::<N>::zeros();
        for j in 0..S {
            // Horner on β_j(θ)/θ and ℓ_j(θ).
            let (mut beta, mut ell) = (0.0, 0.0);
            for k in (0..S).rev() {
                beta = beta * theta + b.beta[j][k];
                ell = ell * theta + b.ell[j][k];
            }
            q += (self.h * beta * theta) * self.stage_velocities[j];
            q_dot += ell * self.stage_velocities[j];
        }
        (q, q_dot)
    }

    /// `v(θ)` and, when asked, `dv/dθ(θ)`.
    fn velocity(&self, theta: f64, derivative: bool) -> (Vector<N>, Vector<N>) {
        let b = self.basis;
        let mut v = Vector::<N>::zeros();
        let mut dv = Vector::<N>::zeros();
        for i in 0..b.len {
            // ℓ_i(θ) and ℓ_i'(θ) by a running product.
            let (source, denominator) = b.source(i);
            let (mut p, mut dp) = (denominator, 0.0);
            for m in 0..b.len {
                if m != i {
                    let f = theta - b.node(m);
                    if derivative {
                        dp = dp * f + p;
                    }
                    p *= f;
                }
            }
            let value = match source {
                Source::Start => &self.start.v,
                Source::Stage(j) => &self.stage_velocities[j],
                Source::End => &self.step_end.v,
            };
            v += p * value;
            if derivative {
                dv += dp * value;
            }
        }
        (v, dv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tableau::Method;

    fn check_basis<const S: usize>(method: Method) {
        let tab = Tableau::<S>::new(method).unwrap();
        let basis = DenseBasis::new(&tab);
        for j in 0..S {
            // ℓ_j(c_i) = δ_ij and β_j(1) = b_j.
            for i in 0..S {
                let mut ell = 0.0;
                for k in (0..S).rev() {
                    ell = ell * tab.c[i] + basis.ell[j][k];
                }
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!((ell - expected).abs() < 1e-12, "{method} s={S}: l_{j}(c_{i}) = {ell:e}");
            }
            let beta_one: f64 = basis.beta[j].iter().sum();
            assert!((beta_one - tab.b[j]).abs() < 1e-13, "{method} s={S}: beta_{j}(1) {beta_one} vs b {}", tab.b[j]);
        }
    }

    #[test]
    fn position_basis_interpolates_and_integrates_to_the_weights() {
        check_basis::<1>(Method::Gauss);
        check_basis::<2>(Method::Gauss);
        check_basis::<3>(Method::Gauss);
        check_basis::<5>(Method::Gauss);
        check_basis::<2>(Method::LobattoIIIAB);
        check_basis::<3>(Method::LobattoIIIAB);
        check_basis::<4>(Method::LobattoIIIABD);
        check_basis::<1>(Method::SymplecticEulerI);
        check_basis::<1>(Method::SymplecticEulerII);
        check_basis::<2>(Method::LobattoIIIBALda);
    }

    #[test]
    fn velocity_interpolant_has_the_documented_degree() {
        assert_eq!(DenseBasis::new(&Tableau::<2>::new(Method::Gauss).unwrap()).velocity_degree(), 3);
        assert_eq!(DenseBasis::new(&Tableau::<3>::new(Method::LobattoIIIAB).unwrap()).velocity_degree(), 2);
        assert_eq!(DenseBasis::new(&Tableau::<1>::new(Method::SymplecticEulerI).unwrap()).velocity_degree(), 1);
    }
}
