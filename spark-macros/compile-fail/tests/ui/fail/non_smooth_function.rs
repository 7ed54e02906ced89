use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Slider {
        coordinates: [x],
        parameters: { mu = 0.3 },
        lagrangian: dot(x)^2/2 - mu*abs(x),
    }
}

fn main() {}
