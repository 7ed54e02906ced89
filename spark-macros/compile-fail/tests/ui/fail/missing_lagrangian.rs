use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Particle {
        coordinates: [x, y, z],
        constraints: [dot(z) - y*dot(x)],
    }
}

fn main() {}
