use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        lagrangian: .5*dot(x)^2,
    }
}

fn main() {}
