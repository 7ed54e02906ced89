use spark_macros::nonholonomic_system;

// A position constraint written inline: holonomic constraints are effects.
nonholonomic_system! {
    pub struct Pendulum {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - y,
        constraints: [ holonomic(x^2 + y^2 - 1) ],
    }
}

fn main() {}
