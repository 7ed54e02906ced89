//! The event function of these tests: affine in `t`, `q`, `v`, with an
//! optional quadratic term in `q₀`.

use spark_runtime::{EventGradient, Vector};

/// `g(t,q,v) = w·q + u·v + a·t + b + κ q₀²`, with its gradient.
#[derive(Clone, Copy)]
pub(crate) struct Affine<const N: usize> {
    pub(crate) w: [f64; N],
    pub(crate) u: [f64; N],
    pub(crate) a: f64,
    pub(crate) b: f64,
    pub(crate) kappa: f64,
}

impl<const N: usize> Affine<N> {
    pub(crate) fn gradient(&self, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N> {
        let w = Vector::<N>::from_row_slice(&self.w);
        let u = Vector::<N>::from_row_slice(&self.u);
        let value = w.dot(q) + u.dot(v) + self.a * t + self.b + self.kappa * q[0] * q[0];
        let mut gq = w;
        gq[0] += 2.0 * self.kappa * q[0];
        EventGradient { value, t: self.a, q: gq, v: u }
    }
}
