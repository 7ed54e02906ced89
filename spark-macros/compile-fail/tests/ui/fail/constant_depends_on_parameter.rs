use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        parameters: { m = 1.0 },
        constants: { half_m = m/2 },
        lagrangian: half_m*dot(x)^2,
    }
}

fn main() {}
