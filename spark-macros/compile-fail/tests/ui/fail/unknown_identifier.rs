use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Skate {
        coordinates: [x, y, theta],
        parameters: { m = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + dot(theta)^2/2 + cos(thta),
    }
}

fn main() {}
