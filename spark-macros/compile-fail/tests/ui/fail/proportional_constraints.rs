use spark_macros::nonholonomic_system;

// The second constraint is the first times 2 cos(theta): K has rank 1.
nonholonomic_system! {
    pub struct Skid {
        coordinates: [x, y, theta],
        parameters: { a = 0.5 },
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(theta)^2)/2,
        constraints: [
            dot(y) - a*x*dot(theta),
            2*cos(theta)*dot(y) - 2*a*x*cos(theta)*dot(theta) + sin(t),
        ],
    }
}

fn main() {}
