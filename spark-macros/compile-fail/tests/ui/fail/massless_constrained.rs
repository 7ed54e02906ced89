use spark_macros::nonholonomic_system;

// The arc length `s` of the path has no kinetic energy: the constraint fixes
// its velocity, but a step still needs a regular Lagrangian.
nonholonomic_system! {
    pub struct Odometer {
        coordinates: [x, y, s],
        lagrangian: (dot(x)^2 + dot(y)^2)/2 - (x^2 + y^2)/2,
        constraints: [ dot(s) - x*dot(y) + y*dot(x) ],
    }
}

fn main() {}
