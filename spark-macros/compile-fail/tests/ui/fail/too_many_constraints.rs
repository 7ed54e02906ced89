use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Bead {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ dot(y) - x*dot(x), dot(x) - y*dot(y), dot(x) + dot(y) ],
    }
}

fn main() {}
