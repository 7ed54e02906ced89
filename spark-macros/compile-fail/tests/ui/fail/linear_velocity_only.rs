use spark_macros::nonholonomic_system;

// `L` is linear in dot(x): no mass, and no constraint fixes dot(x).
nonholonomic_system! {
    pub struct Drift {
        coordinates: [x, y],
        lagrangian: y*dot(x) + dot(y)^2/2 - y^2/2,
    }
}

fn main() {}
