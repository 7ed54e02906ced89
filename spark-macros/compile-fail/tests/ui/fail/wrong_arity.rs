use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Plane {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - atan2(y),
    }
}

fn main() {}
