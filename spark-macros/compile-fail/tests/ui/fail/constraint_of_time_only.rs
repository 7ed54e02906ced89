use spark_macros::nonholonomic_system;

// Neither this constraint nor its time derivative `cos(t)` involves a velocity.
nonholonomic_system! {
    pub struct Particle {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ sin(t) ],
    }
}

fn main() {}
