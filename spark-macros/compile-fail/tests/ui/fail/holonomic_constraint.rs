use spark_macros::nonholonomic_system;

nonholonomic_system! {
    /// A position constraint is not a nonholonomic one.
    pub struct Pendulum {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - y,
        constraints: [x^2 + y^2 - 1],
    }
}

fn main() {}
