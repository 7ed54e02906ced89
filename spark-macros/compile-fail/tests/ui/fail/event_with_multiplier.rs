use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Skate {
        coordinates: [x, y, theta],
        lagrangian: dot(x)^2/2 + dot(y)^2/2 + dot(theta)^2/2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        events: { push: rising(psi[0] - 1) },
    }
}

fn main() {}
