use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Sleigh {
        coordinates: [x, y, theta],
        parameters: { tau = 0.4, c = 0.3, mu = 0.2 },
        lagrangian: dot(x)^2/2 + dot(y)^2/2 + dot(theta)^2/2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        effects: {
            rail: constraint(dot(x) - 1),
            friction: nonideal { x: -mu*psi[1] },
        },
        scenes: { Rubbing = [rail, friction] },
    }
}

fn main() {}
