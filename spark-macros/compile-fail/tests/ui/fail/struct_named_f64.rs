use spark_macros::nonholonomic_system;

// The generated code names `f64` (fields, locals): a struct of that name
// would shadow the primitive type in its module.
nonholonomic_system! {
    pub struct f64 {
        coordinates: [x],
        parameters: { k = 1.0 },
        lagrangian: dot(x)^2/2 - k*x^2/2,
    }
}

fn main() {}
