use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub struct Oscillator {
        coordinates: [x],
        lagrangian: xdot^2/2 - x^2/2,
    }
}

fn main() {}
