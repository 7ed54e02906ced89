use spark_macros::nonholonomic_system;

// `(2 - 2)` folds to 0: the mass matrix would be `inf`.
nonholonomic_system! {
    pub struct Particle {
        coordinates: [x],
        parameters: { m = 1.0 },
        lagrangian: m/(2 - 2)*dot(x)^2,
    }
}

fn main() {}
