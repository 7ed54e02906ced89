use spark_macros::nonholonomic_system;

// The base is fine; the scene adds a third constraint to two coordinates.
nonholonomic_system! {
    pub struct Puck {
        coordinates: [x, y],
        lagrangian: (dot(x)^2 + dot(y)^2)/2,
        constraints: [ dot(y) - x*dot(x) ],
        effects: {
            rail: holonomic(y - x^2),
            belt: constraint(dot(x) - cos(t)),
        },
        scenes: { Railed = [rail], Overdone = [rail, belt] },
    }
}

fn main() {}
