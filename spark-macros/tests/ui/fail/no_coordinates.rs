use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub struct Nothing {
        coordinates: [],
        lagrangian: 1,
    }
}

fn main() {}
