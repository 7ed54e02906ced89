use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        parameters: { m = 2*x },
        lagrangian: m*dot(x)^2/2,
    }
}

fn main() {}
