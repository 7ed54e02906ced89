use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Arm {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - atan(y, x),
    }
}

fn main() {}
