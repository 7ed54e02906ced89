use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Pendulum {
        coordinates: [phi],
        lagrangian: dot(phi)^2/2 + cosine(phi),
    }
}

fn main() {}
