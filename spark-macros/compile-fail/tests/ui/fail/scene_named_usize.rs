use spark_macros::nonholonomic_system;

// Each scene is a struct of its own; the generated code names `usize`.
nonholonomic_system! {
    pub struct Cart {
        coordinates: [x],
        lagrangian: dot(x)^2/2,
        effects: { spring: potential(x^2/2) },
        scenes: { usize = [spring] },
    }
}

fn main() {}
