use spark_runtime::nonholonomic_system;

nonholonomic_system! {
    pub struct Pendulum {
        coordinates: [phi],
        lagrangian: dot(phi)^2/2 + cosine(phi),
    }
}

fn main() {}
