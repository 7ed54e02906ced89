use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub Particle {
        coordinates: [x],
        lagrangian: dot(x)^2/2,
    }
}

fn main() {}
