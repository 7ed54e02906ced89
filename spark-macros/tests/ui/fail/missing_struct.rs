use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub Particle {
        coordinates: [x],
        lagrangian: dot(x)^2/2,
    }
}

fn main() {}
