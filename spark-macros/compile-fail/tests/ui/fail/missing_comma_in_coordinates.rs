use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
    }
}

fn main() {}
