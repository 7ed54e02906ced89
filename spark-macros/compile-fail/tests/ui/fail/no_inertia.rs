use spark_macros::nonholonomic_system;

// The wheel angle `phi` was declared but its kinetic energy forgotten.
nonholonomic_system! {
    pub struct Cart {
        coordinates: [x, y, phi],
        parameters: { m = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) - m*x,
    }
}

fn main() {}
