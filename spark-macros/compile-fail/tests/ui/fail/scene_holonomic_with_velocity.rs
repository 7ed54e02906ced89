use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Cart {
        coordinates: [x, y],
        lagrangian: dot(x)^2/2 + dot(y)^2/2,
        effects: { rod: holonomic(x*dot(x) + y) },
        scenes: { Rod = [rod] },
    }
}

fn main() {}
