//! The start states of the paper's systems and the restarting step loop
//! that the one-step benches (`step`, `newton_stop`, `linalg`) share.

use spark_runtime::{NonholonomicSystem, State, Stepper, Vector};

/// How far a timed trajectory runs before it restarts from its initial
/// condition: far enough to average over the motion, short enough that the
/// trajectory stays in the paper's regime.
pub const RESTART_AFTER: f64 = 10.0;

/// The start states of the hand-written paper systems
/// (`spark_runtime::fixtures::paper`).
pub struct Starts {
    pub particle: State<3>,
    pub skate: State<3>,
    pub robot: State<4>,
    /// The McLachlan–Perlmutter particles (n = 7), at rest.
    pub mp7: State<7>,
}

impl Starts {
    /// The start states the one-step benches use.
    pub fn paper() -> Self {
        Starts {
            particle: State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0)),
            skate: State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0)),
            robot: State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0)),
            mp7: State::new(
                0.0,
                Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
                Vector::<7>::zeros(),
            ),
        }
    }
}

/// One warm-started step of size `h` per call, along the trajectory from
/// `start`, restarting (state and warm start) once past
/// [`RESTART_AFTER`]; returns a coordinate of the new state so that the
/// step cannot be optimized away. Panics if a step fails: a bench has no
/// caller to hand the error to.
pub fn restarting_steps<'a, Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &'a mut Stepper<Sys, N, M, S, D>,
    start: State<N>,
    h: f64,
) -> impl FnMut() -> f64 + 'a
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut s = start;
    move || {
        if s.t > RESTART_AFTER {
            s = start;
            stepper.reset_warm_start();
        }
        s = stepper.step(&s, h).unwrap().state;
        std::hint::black_box(s.q[0])
    }
}
