use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x, m],
        parameters: { m = 1.0 },
        lagrangian: dot(x)^2/2,
    }
}

fn main() {}
