use spark_macros::nonholonomic_system;

// The kinetic energy is missing: ∇²_vv L ≡ 0, although every velocity appears
// in the constraint.
nonholonomic_system! {
    pub struct Bead {
        coordinates: [x, y],
        parameters: { k = 1.0 },
        lagrangian: -k/2*(x^2 + y^2),
        constraints: [ dot(x) - y*dot(y) ],
    }
}

fn main() {}
