use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Ball {
        coordinates: [y],
        parameters: { g = 9.81 },
        lagrangian: dot(y)^2/2 - g*y,
        events: { ground: falling(height) terminal },
    }
}

fn main() {}
