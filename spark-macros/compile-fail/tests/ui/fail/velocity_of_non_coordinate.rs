use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        parameters: { m = 1.0 },
        lagrangian: m*dot(x)^2/2 + dot(m),
    }
}

fn main() {}
