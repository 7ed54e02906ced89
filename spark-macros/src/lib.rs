//! The `nonholonomic_system!` procedural macro. Deliberately thin: all parsing,
//! differentiation and code emission lives in the plain library
//! `spark-symbolic`, where it is testable without a compiler in the loop.
use proc_macro::TokenStream;

/// Declares a nonholonomic Lagrangian system `L(t, q, v)`, `0 = k(t, q, v)`
/// and generates a type implementing `spark_runtime::NonholonomicSystem<N, M>`
/// with exact, simplified, allocation-free derivatives.
///
/// ```
/// use spark_runtime::{nonholonomic_system, NonholonomicSystem, Vector};
///
/// nonholonomic_system! {
///     /// Skate on an inclined plane (doc comments and attributes pass through).
///     pub struct Skate {
///         coordinates: [x, y, theta],
///         parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = pi/2 },
///         lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
///         constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
///     }
/// }
///
/// let mut skate = Skate::default();
/// skate.g = 9.81; // parameters are public f64 fields: sweeps need no recompilation
/// let (q, v) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
/// assert_eq!(skate.constraint(0.0, &q, &v)[0], 0.0);
/// ```
///
/// # Grammar
///
/// ```text
/// declaration := attribute* visibility? "struct" Name "{" section ("," section)* ","? "}"
/// section     := "coordinates"     ":" "[" name ("," name)* ","? "]"           required, at least one
///              | "parameters"      ":" "{" (name "=" const_expr),* ","? "}"    runtime f64 fields + defaults
///              | "constants"       ":" "{" (name "=" const_expr),* ","? "}"    folded at compile time
///              | "lagrangian"      ":" expr                                    required
///              | "constraints"     ":" "[" (expr),* ","? "]"                  optional; none or [] = unconstrained
///              | "forces"          ":" "{" (coordinate ":" expr),* ","? "}"   external force f(t,q,v); none or {} = 0
///              | "nonideal_forces" ":" "{" (coordinate ":" expr),* ","? "}"   non-ideal constraint force N(t,q,v,ψ); none or {} = 0
///              | "events"          ":" "{" (name ":" event),* ","? "}"        zeros of g(t,q,v) the driver locates; none or {} = none
/// event       := ("rising" | "falling" | "crossing")? "(" expr ")" "terminal"?  or  expr "terminal"?
/// ```
///
/// An event is a smooth function `g(t,q,v)` (no multipliers); the generated
/// type gets `HAS_EVENTS = true`, `EVENTS` (name, direction, terminal, source
/// text) and `event_value`/`event_gradient` (`g`, `∂g/∂t`, `∂g/∂q`, `∂g/∂v`).
/// `rising` counts crossings from negative to non-negative, `falling` the
/// reverse, `crossing` or no keyword both; `terminal` ends `integrate` at the
/// first counted crossing (see `spark_runtime::events`). An `event(…)`
/// effect declares an event that a scene selects by name.
///
/// Attributes on the struct stay on it; a `#[cfg(…)]` among them also goes
/// on every item generated for it, so a false condition removes the system
/// with its implementations.
///
/// Sections may come in any order, each at most once. Expressions use
/// `+ - * /`, unary minus, `^` for powers (integer or real exponents),
/// parentheses, numbers (`1`, `2.5`, `1e-3`), the time `t`, `pi`, the
/// declared names, velocities `dot(x)` of coordinates, and the functions
/// `sqrt exp ln sin cos tan sinh cosh tanh`, `atan2(y, x)` and `atan asin
/// acos` (rewritten as `atan2(x, 1)`, `atan2(x, sqrt(1 - x^2))`,
/// `atan2(sqrt(1 - x^2), x)`). Non-smooth functions (`abs`, `min`, `max`,
/// `sign`, …) are refused with a smooth stand-in to write instead: Newton
/// needs derivatives everywhere.
///
/// `^` binds tighter than unary minus and is right-associative:
/// `-x^2 = -(x^2)`, `a*b^c = a*(b^c)`, `a^b^c = a^(b^c)`, `x^-1 = x^(-1)`;
/// `* /` and `+ -` are left-associative as usual.
///
/// Parameter defaults and constants are constant expressions (numbers, `pi`,
/// functions, constants; a constant may use the constants declared before
/// it). Names must be distinct across coordinates, parameters and constants,
/// and may not be `t`, `pi`, `dot`, a function name, a Rust keyword, or start
/// with `__`. The struct's name (and a scene's) is no Rust keyword, does
/// not start with `__`, and is none of `f64`, `usize`, `bool` and `str`,
/// the primitive types the generated code names. Each constraint must
/// involve the velocities (a position constraint is holonomic: write its
/// time derivative; a constraint of the time alone constrains no motion and
/// is refused). `M`, the number of
/// constraints, is the length of the `constraints` list.
///
/// Declarations whose accelerations no state can determine are compile
/// errors: more constraints than coordinates, a Lagrangian with
/// `∇²_vv L ≡ 0` (no velocity term, or only linear ones), a coordinate whose
/// velocity is in neither the mass matrix `∇²_vv L` nor any constraint (a
/// forgotten kinetic term), fewer velocities in `∇²_vv L` than coordinates
/// minus constraints, a coordinate whose velocity a constraint fixes but
/// which has no column in `∇²_vv L` (the integrators need a regular
/// Lagrangian: the momentum equations of such a coordinate at the stages and
/// at the step's end are dependent), and two constraints whose rows of
/// `K = ∂k/∂v` are proportional. A division whose denominator simplifies to
/// the constant 0 (`m/(2 - 2)`, `dot(x)^2/(x - x)`, a constant that folds
/// to 0) is an error at its `/`, wherever it is written: `lagrangian`,
/// constraints, forces, effects (selected by a scene or not), constants and
/// parameter defaults. (The base of a system with scenes is exempt from the
/// checks on coordinates, since a scene's constraint may fix a velocity and
/// its potential give it inertia; each scene is checked.)
///
/// # Effects and scenes
///
/// A declaration may add optional named effects and scenes that select some
/// of them. The base struct (no effects) is generated as usual, and each
/// scene becomes its own struct, generated from the base declaration with the
/// scene's potentials subtracted from `L` and its constraints appended — so a
/// scene's code is exactly that of the same system declared by hand without
/// the effects it leaves out (no multipliers for absent constraints, constant
/// mass matrices folded, no time derivatives when the scene is autonomous).
///
/// ```text
/// section := … | "effects" ":" "{" (name ":" effect),* ","? "}"
///              | "scenes"  ":" "{" (Name "=" "[" name,* "]"),* ","? "}"
/// effect  := "potential"  "(" expr ")"   U(t,q,v), subtracted from L
///          | "constraint" "(" expr ")"   an extra constraint k(t,q,v) = 0 (must involve velocities)
///          | "holonomic"  "(" expr ")"   g(t,q) = 0, imposed at velocity level as k = g_t + g_q·v
///          | "force"    "{" (coordinate ":" expr),* "}"   external force f(t,q,v), absent components 0
///          | "nonideal" "{" (coordinate ":" expr),* "}"   non-ideal constraint force N(t,q,v,ψ)
///          | "event"    "(" event ")"                  an event (see `events` above), in the scenes that list it
/// ```
///
/// Several `force` effects in a scene add up component by component (so do
/// `nonideal` ones, and both add to `forces:`/`nonideal_forces:` of the base
/// declaration). Inside a `nonideal` effect the multiplier of a constraint
/// is written by the constraint effect's name (`blade` below) and that of a
/// base constraint `j` as `psi[j]`; a scene that selects the non-ideal force
/// must also select the constraints it names. So a constraint effect's name
/// follows the rules of declared names (not `t`, `pi`, a function or a
/// keyword, nor a coordinate, parameter or constant), and a scene's name,
/// the name of a struct, follows the rules of the struct's name. A scene's
/// constraints are the base ones followed by its `constraint`/`holonomic`
/// effects in the order the scene lists them. Holonomic effects also give the generated type
/// `HAS_HOLONOMIC = true` and `holonomic_residual(t, q)` (`g_i`, 0 for the
/// other rows), so the drift of `g` can be measured.
///
/// ```
/// use spark_runtime::{nonholonomic_system, NonholonomicSystem, Vector};
///
/// nonholonomic_system! {
///     pub struct Sled {
///         coordinates: [x, y, theta],
///         parameters: { tau = 0.4, c = 0.3, mu = 0.2 },
///         lagrangian: (dot(x)^2 + dot(y)^2 + dot(theta)^2)/2,
///         effects: {
///             drive: force { theta: tau },
///             damping: force { x: -c*dot(x), y: -c*dot(y), theta: -c*dot(theta) },
///             blade: constraint(cos(theta)*dot(y) - sin(theta)*dot(x)),
///             friction: nonideal { x: -mu*blade*cos(theta), y: -mu*blade*sin(theta) },
///         },
///         scenes: { Gliding = [blade], Driven = [blade, drive, damping], Rubbing = [blade, friction] },
///     }
/// }
/// assert!(!Gliding::HAS_FORCING && Driven::HAS_FORCING && Rubbing::HAS_NONIDEAL_FORCE);
/// let (q, v) = (Vector::<3>::zeros(), Vector::<3>::new(1.0, 0.0, 2.0));
/// assert_eq!(Driven::default().external_force(0.0, &q, &v), Vector::<3>::new(-0.3, 0.0, 0.4 - 0.6));
/// ```
///
/// ```
/// use spark_runtime::{nonholonomic_system, NonholonomicSystem};
///
/// nonholonomic_system! {
///     pub struct Cart {
///         coordinates: [x, y, theta],
///         parameters: { m = 1.0, inertia = 0.5, kappa = 2.0 },
///         lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2,
///         effects: {
///             spring: potential(kappa/2*(x^2 + y^2)),
///             no_slip: constraint(cos(theta)*dot(y) - sin(theta)*dot(x)),
///         },
///         scenes: { Free = [], Skating = [spring, no_slip] },
///     }
/// }
/// assert_eq!((Free::M, Skating::M), (0, 1));
/// ```
///
/// Effect and scene names must be distinct; a scene may not list an effect
/// twice or be named like the base struct; a constraint effect may not share
/// its name with a coordinate, parameter or constant. Compile errors point
/// at: an unknown or repeated coordinate in a force block, `psi[j]` outside a
/// non-ideal force or out of range, an unknown constraint name, a `force`
/// that uses a multiplier (declare it `nonideal`), a holonomic `g` that uses
/// velocities, and a scene selecting a non-ideal force without the
/// constraint whose multiplier it uses.
///
/// `#[spark(crate = path)]` tells the generated code where the runtime is
/// (default `::spark_runtime`).
///
/// # Generated items
/// The struct with one `pub f64` field per parameter, `Default` (the
/// declared defaults), `new()`, the constants `N` and `M`, and the
/// `NonholonomicSystem<N, M>` implementation, including the structure facts
/// the macro proved (`STRUCTURE`, and `CONSTANT_STIFFNESS` for a quadratic
/// potential), the source expressions in neutral text
/// (`SOURCE`) and the operation counts (`OPERATIONS`). See the expansion of a
/// declaration with
/// `cargo run -p spark-symbolic --example expand -- <file.rs> <StructName>`.
///
/// # Errors
/// Every malformed declaration the macro detects is a compile error at the
/// offending token that says what is wrong and, for nearly every mistake,
/// what to write instead (unknown names with the nearest known one,
/// velocities of non-coordinates, duplicate names, wrong arity, non-numeric
/// defaults, missing sections or commas, `.5` for `0.5`, holonomic
/// constraints with their velocity-level form, …). The checks of structure
/// use only the zeros and identities the simplifier proves, so a declaration
/// that compiles may still be singular at some states (the runtime reports
/// those). The macro never panics.
#[proc_macro]
pub fn nonholonomic_system(input: TokenStream) -> TokenStream {
    spark_symbolic::expand(input.into()).into()
}
