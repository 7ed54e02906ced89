//! A [`Tableau`] as plain serializable arrays, for programs outside Rust that
//! rebuild the SPARK equations (6.1) from the coefficients alone: the CasADi
//! cross-check and the Python peers of `spark work-precision`.
//!
//! The internal constraint conditions are spelled out as the equations the
//! paper writes ([`ConditionEquation`]), so a reader needs no knowledge of
//! [`ConditionRows`].

use super::{ConditionRows, Tableau};

/// The coefficients of an `s`-stage SPARK method as vectors and row-major
/// nested arrays.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TableauTable {
    /// The method's key ([`Method::key`](crate::Method::key)), e.g. `"lobatto-iiia-b"`.
    pub key: &'static str,
    /// The method's table label ([`Method::label`](crate::Method::label)), e.g. `"Lobatto IIIA-B s=2"`.
    pub label: String,
    /// Number of stages `s`.
    pub stages: usize,
    /// Nodes `c`.
    pub c: Vec<f64>,
    /// `A` (for `q`), row-major.
    pub a: Vec<Vec<f64>>,
    /// `Â` (for `F`).
    pub a_hat: Vec<Vec<f64>>,
    /// `Ã` (for `R`).
    pub a_tilde: Vec<Vec<f64>>,
    /// `b`.
    pub b: Vec<f64>,
    /// `b̂`.
    pub b_hat: Vec<f64>,
    /// `b̃`.
    pub b_tilde: Vec<f64>,
    /// The `s − 1` internal constraint conditions.
    pub conditions: Vec<ConditionEquation>,
}

/// One internal constraint condition of a SPARK step, as an equation.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ConditionEquation {
    /// `0 = Σ_j ω_j K_j` (eq. 6.1e).
    Weights {
        /// `ω_j`.
        omega: Vec<f64>,
    },
    /// `0 = k(t0 + c h, q0 + h Σ_j α_j V_j, Σ_j β_j V_j)` (e.g. the modified
    /// Lobatto IIIA-B condition of §8.4: `c = ½`, `α = (½, 0)`, `β = (1, 0)`).
    Point {
        /// Time node.
        c: f64,
        /// Position weights `α_j`.
        alpha: Vec<f64>,
        /// Velocity weights `β_j`.
        beta: Vec<f64>,
    },
    /// `0 = Ψ_i − Ψ_j` (0-based stage indices; McLachlan–Perlmutter, eq. 7.3).
    MultiplierDifference {
        /// First stage.
        i: usize,
        /// Second stage.
        j: usize,
    },
}

impl TableauTable {
    /// The coefficients of `tableau`, with its condition rows written as
    /// equations.
    pub fn of<const S: usize>(tableau: &Tableau<S>) -> Self {
        let rows = |m: &[[f64; S]; S]| m.iter().map(|r| r.to_vec()).collect::<Vec<_>>();
        let conditions = (0..S.saturating_sub(1)).map(|i| condition(tableau, i)).collect();
        Self {
            key: tableau.method.key(),
            label: tableau.method.label(S),
            stages: S,
            c: tableau.c.to_vec(),
            a: rows(&tableau.a),
            a_hat: rows(&tableau.a_hat),
            a_tilde: rows(&tableau.a_tilde),
            b: tableau.b.to_vec(),
            b_hat: tableau.b_hat.to_vec(),
            b_tilde: tableau.b_tilde.to_vec(),
            conditions,
        }
    }
}

/// Internal condition `i` (`0 ≤ i < S − 1`) of `tableau` as an equation.
fn condition<const S: usize>(tableau: &Tableau<S>, i: usize) -> ConditionEquation {
    let first = |x: f64| (0..S).map(|j| if j == 0 { x } else { 0.0 }).collect();
    match tableau.conditions {
        ConditionRows::Omega => ConditionEquation::Weights { omega: tableau.omega[i].to_vec() },
        // Paper §8.4: 0 = k(t0 + h/2, q0 + (h/2) V_1, V_1).
        ConditionRows::MidpointConstraint => ConditionEquation::Point { c: 0.5, alpha: first(0.5), beta: first(1.0) },
        ConditionRows::EqualMultipliers => ConditionEquation::MultiplierDifference { i, j: i + 1 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Method;

    #[test]
    fn every_method_keeps_its_coefficients_and_conditions() {
        let t = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        let table = TableauTable::of(&t);
        assert_eq!((table.key, table.stages), ("lobatto-iiia-b", 2));
        assert_eq!(table.a, vec![t.a[0].to_vec(), t.a[1].to_vec()]);
        assert_eq!(table.a_hat[1], t.a_hat[1].to_vec());
        assert_eq!(table.conditions, vec![ConditionEquation::Weights { omega: t.omega[0].to_vec() }]);
        let lda = TableauTable::of(&Tableau::<2>::new(Method::LobattoIIIBALda).unwrap());
        assert_eq!(lda.conditions, vec![ConditionEquation::MultiplierDifference { i: 0, j: 1 }]);
        let modified = TableauTable::of(&Tableau::<2>::new(Method::ModifiedLobattoIIIAB).unwrap());
        assert_eq!(
            modified.conditions,
            vec![ConditionEquation::Point { c: 0.5, alpha: vec![0.5, 0.0], beta: vec![1.0, 0.0] }]
        );
        assert!(TableauTable::of(&Tableau::<1>::new(Method::Gauss).unwrap()).conditions.is_empty());
    }

    #[test]
    fn serializes_key_label_and_tagged_conditions() {
        let table = TableauTable::of(&Tableau::<2>::new(Method::LobattoIIIBALda).unwrap());
        let json = serde_json::to_value(&table).unwrap();
        assert_eq!(json["key"], "lobatto-iiib-a-lda");
        assert_eq!(json["label"], Method::LobattoIIIBALda.label(2));
        assert_eq!(json["conditions"][0]["kind"], "multiplier_difference");
        assert!(json.get("name").is_none());
    }
}
