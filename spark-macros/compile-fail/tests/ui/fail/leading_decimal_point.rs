use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        lagrangian: .5*dot(x)^2,
    }
}

fn main() {}
