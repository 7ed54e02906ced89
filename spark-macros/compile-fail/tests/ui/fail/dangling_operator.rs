use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2,
        constraints: [dot(z) - y*],
    }
}

fn main() {}
