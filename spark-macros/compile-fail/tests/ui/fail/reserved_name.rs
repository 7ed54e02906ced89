use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Clock {
        coordinates: [t],
        lagrangian: dot(t)^2/2,
    }
}

fn main() {}
