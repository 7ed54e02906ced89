use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Oscillator {
        coordinates: [x],
        lagrangian: xdot^2/2 - x^2/2,
    }
}

fn main() {}
