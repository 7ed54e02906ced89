use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        lagrangian: ,
    }
}

fn main() {}
