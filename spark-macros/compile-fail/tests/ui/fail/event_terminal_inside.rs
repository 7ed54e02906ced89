use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Ball {
        coordinates: [y],
        lagrangian: dot(y)^2/2 - 9.81*y,
        events: { ground: falling(y terminal) },
    }
}

fn main() {}
