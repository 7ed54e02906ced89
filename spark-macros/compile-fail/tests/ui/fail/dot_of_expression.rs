use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x, y],
        lagrangian: dot(x + y)^2/2,
    }
}

fn main() {}
