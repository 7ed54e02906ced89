use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Oscillator {
        coordinates: [x],
        lagrangian: dot(x)**2/2 - x.powi(2)/2,
    }
}

fn main() {}
