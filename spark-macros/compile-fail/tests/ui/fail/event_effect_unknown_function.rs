use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Ball {
        coordinates: [y],
        lagrangian: dot(y)^2/2 - 9.81*y,
        effects: { kink: event(abs(y) - 1) },
        scenes: { Kinked = [kink] },
    }
}

fn main() {}
