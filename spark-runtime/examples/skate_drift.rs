//! Round-off drift of long fixed-step runs on the skate (paper initial
//! values, T = 10): the global error of the 3-stage Lobatto IIIA-B (or,
//! with `gauss`, Gauss) SPARK method against the closed-form solution, for
//! several Newton settings; also prints how far the GBS reference is from
//! the closed form.
//! `cargo run --release --example skate_drift -- [gauss] [steps...]`.

use spark_runtime::fixtures::paper::Skate;
use spark_runtime::reference::{integrate, ReferenceOptions};
use spark_runtime::{Method, NewtonOptions, State, Stepper, Tableau, Vector};

fn run(opts: NewtonOptions, n: usize, method: Method) -> (State<3>, f64) {
    let tab = Tableau::<3>::new(method).expect("s = 3");
    let mut st = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab).with_options(opts);
    let h = 10.0 / n as f64;
    let mut s = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let mut it = 0;
    for _ in 0..n {
        let r = st.step(&s, h).expect("step");
        it += r.iterations;
        s = r.state;
    }
    (s, it as f64 / n as f64)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let method = if args.first().map(String::as_str) == Some("gauss") { Method::Gauss } else { Method::LobattoIIIAB };
    let ns: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    let ns = if ns.is_empty() { vec![4096, 16384, 65536] } else { ns };
    let sys = Skate::default();
    let (q0, v0) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let r14 = integrate::<_, 3, 1>(&sys, 0.0, &q0, &v0, 10.0, &ReferenceOptions::default()).unwrap();
    let tight = ReferenceOptions { rtol: 1e-15, atol: 1e-15, max_rows: 10, ..ReferenceOptions::default() };
    let r15 = integrate::<_, 3, 1>(&sys, 0.0, &q0, &v0, 10.0, &tight).unwrap();
    // Closed form (β = π/2, g = m = I = 1, θ = t, speed along the blade
    // u = sin t): x = (1 − cos 2t)/4, y = t/2 − sin(2t)/4.
    let t: f64 = 10.0;
    let qr = Vector::<3>::new((1.0 - (2.0 * t).cos()) / 4.0, t / 2.0 - (2.0 * t).sin() / 4.0, t);
    let vr = Vector::<3>::new(t.sin() * t.cos(), t.sin() * t.sin(), 1.0);
    for (name, r) in [("GBS 1e-14", &r14), ("GBS 1e-15", &r15)] {
        println!("{name} vs closed form: dq {:.2e} dv {:.2e}", (r.q[0] - qr).amax(), (r.v[0] - vr).amax());
    }
    println!("q_ref {:?} v_ref {:?}", qr.as_slice(), vr.as_slice());
    let d = NewtonOptions::default();
    let variants: Vec<(&str, NewtonOptions)> = vec![
        ("default", d),
        ("tol=0 (stagnation)", NewtonOptions { tolerance: 0.0, ..d }),
        ("no warm start", NewtonOptions { warm_start: false, ..d }),
        ("extrap degree 1", NewtonOptions { extrapolation_degree: 1, ..d }),
        ("tol=0, no warm", NewtonOptions { tolerance: 0.0, warm_start: false, ..d }),
    ];
    for n in ns {
        for (name, o) in &variants {
            let (s, it) = run(*o, n, method);
            let dq = s.q - qr;
            let dv = s.v - vr;
            println!(
                "n={n:7} {name:20} it={it:.2} eq={:.2e} ev={:.2e} dq=[{:+.1e} {:+.1e} {:+.1e}] dv=[{:+.1e} {:+.1e} {:+.1e}]",
                dq.amax(),
                dv.amax(),
                dq[0],
                dq[1],
                dq[2],
                dv[0],
                dv[1],
                dv[2]
            );
        }
    }
}
