use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Cart {
        coordinates: [x, y],
        lagrangian: dot(x)^2/2 + dot(y)^2/2,
        effects: { spring: potential(x^2/2) },
        scenes: { Sprung = [sprig] },
    }
}

fn main() {}
