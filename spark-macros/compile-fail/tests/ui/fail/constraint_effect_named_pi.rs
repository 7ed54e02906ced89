use spark_macros::nonholonomic_system;

nonholonomic_system! {
    pub struct Sleigh {
        coordinates: [x, y, theta],
        parameters: { mu = 0.2 },
        lagrangian: dot(x)^2/2 + dot(y)^2/2 + dot(theta)^2/2,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        effects: {
            pi: constraint(dot(x) - 1),
            friction: nonideal { x: -mu*pi },
        },
        scenes: { Rubbing = [pi, friction] },
    }
}

fn main() {}
