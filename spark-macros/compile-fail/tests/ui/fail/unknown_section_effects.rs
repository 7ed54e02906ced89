use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        parameters: { kappa = 1.0 },
        lagrangian: dot(x)^2/2,
        effect: { spring: potential(kappa/2*x^2) },
        scenes: { Sprung = [spring] },
    }
}

fn main() {}
