use spark_macros::nonholonomic_system;

// Both constraints have K = ∂k/∂v = (0, 1, 0): they can never both be imposed.
nonholonomic_system! {
    pub struct Belt {
        coordinates: [x, y, theta],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(theta)^2)/2,
        constraints: [ dot(y) - sin(t), dot(y) - x ],
    }
}

fn main() {}
