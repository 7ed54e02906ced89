use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        lagrangian: ,
    }
}

fn main() {}
