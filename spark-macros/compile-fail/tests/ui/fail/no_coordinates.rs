use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Nothing {
        coordinates: [],
        lagrangian: 1,
    }
}

fn main() {}
