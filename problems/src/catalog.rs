//! The one catalogue of every system the `problems` crate offers, and the one
//! dispatch from run-time choices (system, stage count) to the
//! monomorphized code.
//!
//! Each entry is declared once in the `catalog!` list at the bottom of this
//! file: the type, `N`, `M`, the command-line name, a one-line description, a
//! consistent default initial state and a default step and final time.
//! Everything else (structure facts, effects, coordinates, parameters,
//! operation counts) is read from the type's [`NonholonomicSystem`] impl, so
//! the listing cannot disagree with the code.
//!
//! Dispatch has two levels, because the stepper's type needs the stage count
//! `S` and `D = S(N+M)+N`, which stable Rust cannot compute from a generic
//! `N`:
//! - [`visit_system`] maps a [`SystemKind`] to a call of
//!   [`SystemVisitor::visit`] with the concrete type (and `Y = 2N` for
//!   first-order ODE peers);
//! - [`Dispatch::with_stages`], implemented for every registered type by the
//!   list, maps a run-time stage count to [`StageVisitor::visit`] with
//!   literal `S` and `D`. `spark run` and `spark work-precision` share it;
//!   [`Dispatch::with_lane_stages`] is the same dispatch for the entries
//!   whose ensembles step in SIMD lanes (`ensemble: lanes`).

use spark_runtime::{EventSpec, NonholonomicSystem, OperationCounts, Structure, SystemSource};

/// Largest stage count compiled into the dispatch. Every family reaches its
/// largest useful order here: Gauss s = 1..5 (order 10), Lobatto IIIA-B and
/// IIIA-B-D s = 2..5 (order 8); the Euler methods and the LDA method have one
/// stage count each. Each extra `S` adds one monomorphized stepper per
/// system and visitor.
pub const MAX_DISPATCH_STAGES: usize = 5;

/// What every registered system type satisfies.
pub trait Registered<const N: usize, const M: usize>:
    NonholonomicSystem<N, M> + Default + Clone + Send + Sync + 'static
{
}
impl<T, const N: usize, const M: usize> Registered<N, M> for T where
    T: NonholonomicSystem<N, M> + Default + Clone + Send + Sync + 'static
{
}

/// Work generic in the stage count, for one system type `Sys`.
pub trait StageVisitor<Sys, const N: usize, const M: usize> {
    /// What the work returns.
    type Output;
    /// Does the work with `S` stages; `D = S(N+M)+N` is the stepper's
    /// unknown count.
    fn visit<const S: usize, const D: usize>(self) -> Self::Output;
}

/// The stage-count dispatch of one registered type (implemented by the
/// `catalog!` list; do not implement it by hand).
pub trait Dispatch<const N: usize, const M: usize>: Registered<N, M> {
    /// Calls `visitor.visit::<S, D>()` for `S = stages`, or says which stage
    /// counts are compiled in.
    fn with_stages<V: StageVisitor<Self, N, M>>(stages: usize, visitor: V) -> Result<V::Output, DispatchError>;

    /// [`Self::with_stages`] for the systems whose ensembles step in SIMD
    /// lanes (entries marked `ensemble: lanes`); `None` for the others,
    /// whose ensembles run member by member. The lane kernel is compiled
    /// once per (system, `S`), so it is compiled only where the catalogue
    /// asks for it.
    fn with_lane_stages<V: StageVisitor<Self, N, M>>(
        stages: usize,
        visitor: V,
    ) -> Option<Result<V::Output, DispatchError>> {
        let _ = (stages, visitor);
        None
    }

    /// The work-precision study runs the reversible step-size rule on this
    /// system (entries marked `steps: reversible`, the ones with a step
    /// density): its drivers are compiled only for these.
    const REVERSIBLE_STEPS: bool = false;
}

/// Work generic in the system type.
pub trait SystemVisitor: Sized {
    /// What the work returns.
    type Output;
    /// Does the work for `Sys`; `Y = 2N` is the length of the first-order
    /// state `(q, v)` (for ODE solvers).
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        entry: &'static SystemEntry,
    ) -> Self::Output;
}

/// A stage count outside the compiled range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("s = {stages} is not compiled into this program; supported: s = 1..={max}")]
pub struct DispatchError {
    /// The stage count asked for.
    pub stages: usize,
    /// [`MAX_DISPATCH_STAGES`].
    pub max: usize,
}

/// Which optional effects of the system trait a system carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Effects {
    /// External generalized force `f(t,q,v)` ([`NonholonomicSystem::HAS_FORCING`]).
    pub forcing: bool,
    /// Non-ideal constraint force `N(t,q,v,ψ)` ([`NonholonomicSystem::HAS_NONIDEAL_FORCE`]).
    pub nonideal: bool,
    /// Holonomic constraints imposed at velocity level, with a position-level
    /// residual `g(t,q)` ([`NonholonomicSystem::HAS_HOLONOMIC`]).
    pub holonomic: bool,
}

impl Effects {
    /// Short names of the effects present (`forcing`, `non-ideal`, `holonomic`).
    pub fn names(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        if self.forcing {
            v.push("forcing");
        }
        if self.nonideal {
            v.push("non-ideal");
        }
        if self.holonomic {
            v.push("holonomic");
        }
        v
    }
    /// Energy is not conserved because of an effect (forcing or friction).
    pub fn does_work(&self) -> bool {
        self.forcing || self.nonideal
    }
}

/// One registered system: static facts, read from its trait impl where they
/// exist there.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SystemEntry {
    /// The typed handle.
    pub kind: SystemKind,
    /// Command-line name (lower-case, hyphenated).
    pub name: &'static str,
    /// The type's name ([`spark_runtime::SystemSource::name`]).
    pub type_name: &'static str,
    /// The type's path, as written in the catalogue.
    pub path: &'static str,
    /// One-line description.
    pub description: &'static str,
    /// Number of coordinates `N`.
    pub n: usize,
    /// Number of constraints `M`.
    pub m: usize,
    /// Structure facts proved by the macro (or declared by hand).
    pub structure: Structure,
    /// `CONSTANT_STIFFNESS` (a quadratic potential).
    pub constant_stiffness: bool,
    /// `DIAGONAL_STIFFNESS` (a potential that is a sum of functions of one
    /// coordinate each, not quadratic).
    pub diagonal_stiffness: bool,
    /// Optional effects.
    pub effects: Effects,
    /// Coordinate names.
    pub coordinates: &'static [&'static str],
    /// Runtime parameter names (defaults: [`SystemEntry::default_parameters`]).
    pub parameter_names: &'static [&'static str],
    /// Operation counts of the generated code (zeros for hand-written types).
    pub operations: OperationCounts,
    /// The declaration's expressions ([`NonholonomicSystem::SOURCE`]): the
    /// Lagrangian and the constraints as the Python package's `info` shows
    /// them. Not part of `spark list --json`.
    #[serde(skip)]
    pub source: SystemSource,
    /// One of the paper's §8 systems (they have the CasADi C and num-dual
    /// peers; SciPy's run on every system without external or non-ideal
    /// forces).
    pub paper: bool,
    /// Default initial time.
    pub t0: f64,
    /// Default initial coordinates.
    pub q0: &'static [f64],
    /// Default initial velocities, consistent with the constraints at `(t0, q0)`.
    pub v0: &'static [f64],
    /// Default final time of `spark run`.
    pub t_end: f64,
    /// Default step size of `spark run`.
    pub h: f64,
}

impl SystemEntry {
    /// The parameters with their default values, in declaration order.
    pub fn default_parameters(&'static self) -> Vec<(String, f64)> {
        struct Defaults;
        impl SystemVisitor for Defaults {
            type Output = Vec<f64>;
            fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
                self,
                _: &'static SystemEntry,
            ) -> Vec<f64> {
                Sys::default().parameter_values()
            }
        }
        let values = visit_system(self.kind, Defaults);
        self.parameter_names.iter().map(|p| p.to_string()).zip(values).collect()
    }

    /// The effects present as a short text (`forcing, holonomic`; `—` when none).
    pub fn effects_text(&self) -> String {
        let names = self.effects.names();
        if names.is_empty() {
            "—".into()
        } else {
            names.join(", ")
        }
    }
}

/// Facts about one system for `spark list --json` (the entry plus the
/// parameter defaults, which need a value of the type).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SystemInfo {
    /// The static entry.
    #[serde(flatten)]
    pub entry: SystemEntry,
    /// Runtime parameters with their default values.
    pub parameters: Vec<(String, f64)>,
}

impl SystemKind {
    /// The catalogue entry.
    pub fn entry(self) -> &'static SystemEntry {
        &CATALOG[self as usize]
    }
    /// The command-line name.
    pub fn key(self) -> &'static str {
        self.entry().name
    }
    /// Looks a name up (see [`lookup`]).
    pub fn parse(name: &str) -> Result<Self, LookupError> {
        lookup(name).map(|e| e.kind)
    }
    /// The entry and its parameter defaults.
    pub fn info(self) -> SystemInfo {
        let entry = self.entry();
        SystemInfo { entry: *entry, parameters: entry.default_parameters() }
    }
}

/// A name that is not in the catalogue.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{}", lookup_message(self))]
pub struct LookupError {
    /// The name given.
    pub name: String,
    /// The closest registered name, if one is close.
    pub suggestion: Option<&'static str>,
    /// Every registered name, comma-separated.
    pub known: String,
    /// The name is a catalogue system that this build leaves out (the crate
    /// feature `full` is off).
    pub left_out: bool,
}

fn lookup_message(e: &LookupError) -> String {
    if e.left_out {
        format!(
            "system `{}` is in the full catalogue, which this build leaves out (built with \
             --no-default-features); build `problems` with its default features to use it; this build knows: {}",
            e.name, e.known
        )
    } else {
        format!("unknown system `{}`{}; known: {} (see `spark list`)", e.name, did_you_mean(&e.suggestion), e.known)
    }
}

/// ` (did you mean `x`?)` or nothing: the tail of a lookup error message.
pub fn did_you_mean(s: &Option<&'static str>) -> String {
    s.map(|s| format!(" (did you mean `{s}`?)")).unwrap_or_default()
}

/// Lower-case with `-`, `_` and spaces removed: `Rod_Pendulum` and
/// `rod-pendulum` name the same system.
fn normalize(name: &str) -> String {
    name.chars().filter(|c| !matches!(c, '-' | '_' | ' ')).flat_map(char::to_lowercase).collect()
}

/// Edit distance (insertions, deletions, substitutions).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// The candidate nearest to `name` by edit distance, if within a third of
/// its length (at least 2 edits), or one that contains it.
pub fn nearest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let n = normalize(name);
    let best = candidates.into_iter().map(|c| (edit_distance(&n, &normalize(c)), c)).min_by_key(|(d, _)| *d)?;
    let limit = (n.chars().count() / 3).max(2);
    (best.0 <= limit).then_some(best.1)
}

/// Finds a system by command-line name or type name, ignoring case, `-` and
/// `_` (`skate`, `Skate`, `body_skating`, `BodySkating`). Names win over type
/// names (the hand-written `RodPendulum` is `rod-pendulum-hand`).
pub fn lookup(name: &str) -> Result<&'static SystemEntry, LookupError> {
    let key = normalize(name);
    CATALOG
        .iter()
        .find(|e| normalize(e.name) == key)
        .or_else(|| CATALOG.iter().find(|e| normalize(e.type_name) == key))
        .ok_or_else(|| {
            let suggestion = if key.is_empty() {
                None
            } else {
                nearest(name, CATALOG.iter().map(|e| e.name))
                    .or_else(|| CATALOG.iter().find(|e| normalize(e.name).contains(&key)).map(|e| e.name))
            };
            let left_out = LEFT_OUT.iter().any(|n| normalize(n) == key);
            LookupError { name: name.to_string(), suggestion, known: names().join(", "), left_out }
        })
}

/// Every registered command-line name, in catalogue order.
pub fn names() -> Vec<&'static str> {
    CATALOG.iter().map(|e| e.name).collect()
}

/// Every catalogue entry, in order (the paper's first).
pub fn entries() -> &'static [SystemEntry] {
    &CATALOG
}

/// Declares the catalogue: the [`SystemKind`] enum, the static entries,
/// [`visit_system`] and the [`Dispatch`] impls. One block per system, in two
/// groups: the paper's systems, always compiled, and the rest, compiled with
/// the crate feature `full` (on by default):
///
/// ```text
/// paper: [ Variant { ty: path::Type, n: N, m: M, [ensemble: lanes,] [steps: reversible,] name: "cli-name", peers: paper|plain,
///     about: "one line", q0: [..], v0: [..], t_end: T, h: H }, .. ]
/// full: [ .. ]
/// ```
macro_rules! catalog {
    (
        paper: [$( $(#[$pdoc:meta])* $pvariant:ident { $($pfield:tt)* } ),* $(,)?]
        full: [$( $(#[$fdoc:meta])* $fvariant:ident { $($ffield:tt)* } ),* $(,)?]
    ) => {
        /// Every system the command line knows; [`SystemKind::entry`] has the facts.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
        pub enum SystemKind {
            $( $(#[$pdoc])* $pvariant, )*
            $( $(#[$fdoc])* #[cfg(feature = "full")] $fvariant, )*
        }

        impl SystemKind {
            /// Every system, in catalogue order (the paper's four first).
            pub const ALL: &'static [SystemKind] = &[
                $(SystemKind::$pvariant,)*
                $(#[cfg(feature = "full")] SystemKind::$fvariant,)*
            ];
        }

        static CATALOG: [SystemEntry; SystemKind::ALL.len()] = [
            $( catalog!(@entry $pvariant { $($pfield)* }), )*
            $( #[cfg(feature = "full")] catalog!(@entry $fvariant { $($ffield)* }), )*
        ];

        /// Command-line names of the systems this build leaves out (those
        /// of the feature `full` when it is off).
        pub const LEFT_OUT: &[&str] = &[
            $( #[cfg(not(feature = "full"))] catalog!(@name { $($ffield)* }), )*
        ];

        /// Calls `visitor` with the concrete type of `kind`.
        pub fn visit_system<V: SystemVisitor>(kind: SystemKind, visitor: V) -> V::Output {
            match kind {
                $( SystemKind::$pvariant => catalog!(@visit visitor, kind { $($pfield)* }), )*
                $( #[cfg(feature = "full")] SystemKind::$fvariant => catalog!(@visit visitor, kind { $($ffield)* }), )*
            }
        }

        $( catalog!(@dispatch { $($pfield)* }); )*
        $( #[cfg(feature = "full")] catalog!(@dispatch { $($ffield)* }); )*
    };
    (@entry $variant:ident {
        ty: $ty:ty, n: $n:literal, m: $m:literal, $(ensemble: $ensemble:ident,)? $(steps: $steps:ident,)? name: $name:literal, peers: $peers:ident,
        about: $about:literal, q0: [$($q0:expr),* $(,)?], v0: [$($v0:expr),* $(,)?], t_end: $t_end:expr, h: $h:expr $(,)?
    }) => {
        SystemEntry {
            kind: SystemKind::$variant,
            name: $name,
            type_name: <$ty as NonholonomicSystem<$n, $m>>::SOURCE.name,
            path: stringify!($ty),
            description: $about,
            n: $n,
            m: $m,
            structure: <$ty as NonholonomicSystem<$n, $m>>::STRUCTURE,
            constant_stiffness: <$ty as NonholonomicSystem<$n, $m>>::CONSTANT_STIFFNESS,
            diagonal_stiffness: <$ty as NonholonomicSystem<$n, $m>>::DIAGONAL_STIFFNESS,
            effects: Effects {
                forcing: <$ty as NonholonomicSystem<$n, $m>>::HAS_FORCING,
                nonideal: <$ty as NonholonomicSystem<$n, $m>>::HAS_NONIDEAL_FORCE,
                holonomic: <$ty as NonholonomicSystem<$n, $m>>::HAS_HOLONOMIC,
            },
            coordinates: <$ty as NonholonomicSystem<$n, $m>>::SOURCE.coordinates,
            parameter_names: <$ty as NonholonomicSystem<$n, $m>>::SOURCE.parameters,
            operations: <$ty as NonholonomicSystem<$n, $m>>::OPERATIONS,
            source: <$ty as NonholonomicSystem<$n, $m>>::SOURCE,
            paper: catalog!(@paper $peers),
            t0: 0.0,
            q0: &[$($q0 as f64),*],
            v0: &[$($v0 as f64),*],
            t_end: $t_end,
            h: $h,
        }
    };
    (@name { ty: $ty:ty, n: $n:literal, m: $m:literal, $(ensemble: $ensemble:ident,)? $(steps: $steps:ident,)? name: $name:literal, $($rest:tt)* }) => { $name };
    (@visit $visitor:ident, $kind:ident { ty: $ty:ty, n: $n:literal, m: $m:literal, $($rest:tt)* }) => {
        $visitor.visit::<$ty, $n, $m, { 2 * $n }>($kind.entry())
    };
    (@dispatch {
        ty: $ty:ty, n: $n:literal, m: $m:literal, $(ensemble: $ensemble:ident,)? $(steps: $steps:ident,)?
        name: $name:literal, $($rest:tt)*
    }) => {
        impl Dispatch<$n, $m> for $ty {
            catalog!(@with_stages $n, $m);
            $( catalog!(@ensemble $ensemble $n, $m); )?
            $( catalog!(@steps $steps); )?
        }
    };
    (@ensemble lanes $n:literal, $m:literal) => {
        fn with_lane_stages<V: StageVisitor<Self, $n, $m>>(
            stages: usize,
            visitor: V,
        ) -> Option<Result<V::Output, DispatchError>> {
            Some(catalog!(@stages $n, $m, stages, visitor))
        }
    };
    (@steps reversible) => {
        const REVERSIBLE_STEPS: bool = true;
    };
    (@with_stages $n:literal, $m:literal) => {
        fn with_stages<V: StageVisitor<Self, $n, $m>>(stages: usize, visitor: V) -> Result<V::Output, DispatchError> {
            catalog!(@stages $n, $m, stages, visitor)
        }
    };
    (@stages $n:literal, $m:literal, $stages:ident, $visitor:ident) => {
        match $stages {
            1 => Ok($visitor.visit::<1, { $n + $m + $n }>()),
            2 => Ok($visitor.visit::<2, { 2 * ($n + $m) + $n }>()),
            3 => Ok($visitor.visit::<3, { 3 * ($n + $m) + $n }>()),
            4 => Ok($visitor.visit::<4, { 4 * ($n + $m) + $n }>()),
            5 => Ok($visitor.visit::<5, { 5 * ($n + $m) + $n }>()),
            s => Err(DispatchError { stages: s, max: MAX_DISPATCH_STAGES }),
        }
    };
    (@paper paper) => { true };
    (@paper plain) => { false };
}

catalog! {
    paper: [
        /// Nonholonomic particle (paper §8.1).
        Particle {
            ty: crate::systems::NonholonomicParticle, n: 3, m: 1, name: "particle", peers: paper,
            about: "nonholonomic particle, L = |v|²/2 − q1² − q2², v3 − q2 v1 = 0 (§8.1)",
            q0: [1.0, 0.0, 0.0], v0: [0.0, 1.0, 0.0], t_end: 10.0, h: 0.2,
        },
        /// Skate on an inclined plane (paper §8.2).
        Skate {
            ty: crate::systems::Skate, n: 3, m: 1, name: "skate", peers: paper,
            about: "skate on an inclined plane, cos(θ) ẏ − sin(θ) ẋ = 0 (§8.2)",
            q0: [0.0, 0.0, 0.0], v0: [0.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Mobile robot with fixed orientation and a potential (paper §8.3).
        Robot {
            ty: crate::systems::MobileRobot, n: 4, m: 2, name: "robot", peers: paper,
            about: "mobile robot with fixed orientation and potential 10 sin(q4), two rolling constraints (§8.3)",
            q0: [0.0, 0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.0, 1.0], t_end: 10.0, h: 0.2,
        },
        /// McLachlan–Perlmutter particles, `n = 7` (paper §8.4; member `j = 0`).
        McLachlanPerlmutter7 {
            ty: crate::systems::McLachlanPerlmutter7, n: 7, m: 1, ensemble: lanes, name: "mp7", peers: paper,
            about: "McLachlan–Perlmutter particles, n = 7, chaotic, v1 + q5 v5 + q6 v6 + q7 v7 = 0 (§8.4, member j = 0)",
            q0: [1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0], v0: [0, 0, 0, 0, 0, 0, 0], t_end: 10.0, h: 0.05,
        },
        /// McLachlan–Perlmutter particles with the nonholonomic reading of the
        /// §8.4 constraint (member `j = 0`).
        McLachlanPerlmutter7Nonholonomic {
            ty: crate::systems::McLachlanPerlmutter7Nonholonomic, n: 7, m: 1, ensemble: lanes, name: "mp7-nh", peers: plain,
            about: "McLachlan–Perlmutter particles, n = 7, nonholonomic reading v1 + q2 v5 + q3 v6 + q4 v7 = 0 (§8.4)",
            q0: [1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0], v0: [0, 0, 0, 0, 0, 0, 0], t_end: 100.0, h: 0.05,
        },
    ]
    full: [
        /// Skate on a turning table: rheonomic affine constraint.
        Turntable {
            ty: crate::systems::TurntableSkate, n: 3, m: 1, name: "turntable", peers: plain,
            about: "skate on a table turning at ω(t) = ω0(1 + ε sin νt): rheonomic affine constraint, energy not conserved",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 1.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Appell–Hamel particle: constraint nonlinear in `v`.
        AppellHamel {
            ty: crate::systems::AppellHamel, n: 3, m: 1, name: "appell-hamel", peers: plain,
            about: "Appell–Hamel particle under gravity, v3² − a²(v1² + v2²) = 0 (nonlinear in v)",
            // Falling (v3 < 0): rising would stop at v = 0, where K = ∂k/∂v
            // vanishes and the method's Newton matrix is singular.
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, -0.5], t_end: 5.0, h: 0.05,
        },
        /// The §8.1 particle in a softened Kepler potential: varying time scales.
        Orbit {
            ty: crate::systems::OrbitParticle, n: 3, m: 1, steps: reversible, name: "orbit", peers: plain,
            about: "§8.1 particle in a softened Kepler potential μ/√(x²+y²+ε²): eccentric orbit, time scale varies ≈ 100×",
            q0: [1.0, 0.0, 0.0], v0: [0.0, 0.3, 0.0], t_end: 10.0, h: 0.002,
        },
        /// Chaplygin sleigh on an inclined plane: `q`-dependent mass matrix.
        Sleigh {
            ty: crate::systems::ChaplyginSleigh, n: 3, m: 1, name: "sleigh", peers: plain,
            about: "Chaplygin sleigh on an inclined plane: q-dependent mass matrix, no sideways slip",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Planar double pendulum: no constraints.
        DoublePendulum {
            ty: crate::systems::DoublePendulum, n: 2, m: 0, name: "double-pendulum", peers: plain,
            about: "planar double pendulum, no constraints, non-separable L",
            q0: [1.0, 0.5], v0: [0.0, 0.0], t_end: 10.0, h: 0.01,
        },
        /// Planar rigid body, base declaration of the scenes (no effects).
        Body {
            ty: crate::systems::scenes::Body, n: 3, m: 0, name: "body", peers: plain,
            about: "planar rigid body (x, y, θ), base of the scenes: no effects, free motion",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Scene of `Body` with no effects.
        BodyFree {
            ty: crate::systems::scenes::BodyFree, n: 3, m: 0, name: "body-free", peers: plain,
            about: "scene of body with no effects (same code as body)",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Scene of `Body` with the spring.
        BodySprung {
            ty: crate::systems::scenes::BodySprung, n: 3, m: 0, name: "body-sprung", peers: plain,
            about: "scene of body: spring κ/2 (x² + y²) to the origin",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Scene of `Body` with the spring and the blade.
        BodySkating {
            ty: crate::systems::scenes::BodySkating, n: 3, m: 1, name: "body-skating", peers: plain,
            about: "scene of body: spring + skate blade cos θ ẏ − sin θ ẋ = 0",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Scene of `Body` with the spring, the blade and the moving rail.
        BodyRailed {
            ty: crate::systems::scenes::BodyRailed, n: 3, m: 2, name: "body-railed", peers: plain,
            about: "scene of body: spring + blade + rail ẋ = u cos(νt) (time-dependent affine constraint)",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Scene of `Body` with the spring and the tether.
        BodyTethered {
            ty: crate::systems::scenes::BodyTethered, n: 3, m: 1, name: "body-tethered", peers: plain,
            about: "scene of body: spring + tether x² + y² = ℓ² imposed at velocity level",
            q0: [1.0, 0.0, 0.0], v0: [0.0, 0.5, 0.3], t_end: 10.0, h: 0.1,
        },
        /// `BodySkating` declared by hand without effects or scenes.
        BodySkatingByHand {
            ty: crate::systems::scenes::BodySkatingByHand, n: 3, m: 1, name: "body-skating-by-hand", peers: plain,
            about: "body-skating declared by hand without effects (must equal the scene)",
            q0: [1.0, 0.0, 0.0], v0: [0.5, 0.0, 0.3], t_end: 10.0, h: 0.1,
        },
        /// Point mass under gravity, base of the rod-pendulum scene.
        PointMass {
            ty: crate::systems::scenes::PointMass, n: 2, m: 0, name: "point-mass", peers: plain,
            about: "point mass under gravity (x, y), base of the rod-pendulum scene: free fall",
            q0: [0.6, -0.8], v0: [0.8, 0.6], t_end: 2.0, h: 0.05,
        },
        /// Scene of `PointMass` with the holonomic rod.
        RodPendulum {
            ty: crate::systems::scenes::RodPendulum, n: 2, m: 1, name: "rod-pendulum", peers: plain,
            about: "pendulum: point mass with the rod ½(x² + y² − ℓ²) = 0 imposed as x ẋ + y ẏ = 0 (scene)",
            q0: [0.6, -0.8], v0: [0.8, 0.6], t_end: 10.0, h: 0.05,
        },
        /// Vertical rolling disk.
        VerticalDisk {
            ty: crate::systems::scenes::VerticalDisk, n: 4, m: 2, name: "vertical-disk", peers: plain,
            about: "vertical rolling disk (x, y, θ, φ), rolling without slipping; exact solution known",
            q0: [0.0, 0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Ball on a turntable with time-varying angular velocity.
        BallOnTurntable {
            ty: crate::systems::scenes::BallOnTurntable, n: 5, m: 2, name: "ball-on-turntable", peers: plain,
            about: "ball rolling on a turntable turning at Ω(t) = Ω0(1 + ε sin νt): time-dependent affine constraints",
            // θ = π/2, φ = 0: the constraints read ẋ + r ψ̇ + Ω y = 0, ẏ + r θ̇ − Ω x = 0.
            q0: [1.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2, 0.0], v0: [-0.2, 0.5, 0.0, 0.5, 0.2], t_end: 10.0, h: 0.05,
        },
        /// Flat Chaplygin sleigh, base declaration of the sleigh scenes.
        SleighBase {
            ty: crate::systems::scenes::Sleigh, n: 3, m: 1, name: "sleigh-base", peers: plain,
            about: "Chaplygin sleigh on a horizontal plane, base of the sleigh scenes (no effects)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Scene of the flat sleigh with no effects.
        SleighFree {
            ty: crate::systems::scenes::SleighFree, n: 3, m: 1, name: "sleigh-free", peers: plain,
            about: "scene of sleigh-base with no effects",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Scene of the flat sleigh with the drive torque.
        SleighDriven {
            ty: crate::systems::scenes::SleighDriven, n: 3, m: 1, name: "sleigh-driven", peers: plain,
            about: "scene of sleigh-base: drive torque τ about the vertical axis (forcing)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Scene of the flat sleigh with viscous damping.
        SleighDamped {
            ty: crate::systems::scenes::SleighDamped, n: 3, m: 1, name: "sleigh-damped", peers: plain,
            about: "scene of sleigh-base: viscous damping f = −c v (forcing)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Scene of the flat sleigh with drive and damping.
        SleighDrivenDamped {
            ty: crate::systems::scenes::SleighDrivenDamped, n: 3, m: 1, name: "sleigh-driven-damped", peers: plain,
            about: "scene of sleigh-base: drive torque and viscous damping (forcing)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// The driven, damped sleigh declared by hand.
        SleighDrivenDampedByHand {
            ty: crate::systems::scenes::SleighDrivenDampedByHand, n: 3, m: 1, name: "sleigh-driven-damped-by-hand", peers: plain,
            about: "sleigh-driven-damped declared by hand with a forces: section (must equal the scene)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 0.5], t_end: 10.0, h: 0.05,
        },
        /// Body on an inclined plane, base of the ice-skate scenes (no blade).
        IceSkate {
            ty: crate::systems::scenes::IceSkate, n: 3, m: 0, name: "ice-skate", peers: plain,
            about: "planar body on an inclined plane, base of the skate scenes (no blade, no friction)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Scene: the §8.2 skate with its blade as an effect.
        SkateOnBlade {
            ty: crate::systems::scenes::SkateOnBlade, n: 3, m: 1, name: "skate-on-blade", peers: plain,
            about: "scene of ice-skate: the blade cos θ ẏ − sin θ ẋ = 0 (the §8.2 skate)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Scene: blade plus smoothed dry friction (non-ideal force).
        SkateWithFriction {
            ty: crate::systems::scenes::SkateWithFriction, n: 3, m: 1, name: "skate-with-friction", peers: plain,
            about: "scene of ice-skate: blade + smoothed dry friction μ|ψ| along it (non-ideal constraint force)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Particle under gravity, base of the Appell–Hamel scene.
        FallingParticle {
            ty: crate::systems::scenes::FallingParticle, n: 3, m: 0, name: "falling-particle", peers: plain,
            about: "particle under gravity, base of the appell-hamel-cord scene (free fall)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, -0.5], t_end: 5.0, h: 0.05,
        },
        /// Scene: the Appell–Hamel cord constraint (nonlinear in `v`).
        AppellHamelCord {
            ty: crate::systems::scenes::AppellHamelCord, n: 3, m: 1, name: "appell-hamel-cord", peers: plain,
            about: "scene of falling-particle: cord ż² − a²(ẋ² + ẏ²) = 0, nonlinear in v (Chetaev)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, -0.5], t_end: 5.0, h: 0.05,
        },
        /// Skate driven by a torque and viscously damped (hand-written).
        DrivenSkate {
            ty: spark_runtime::fixtures::effects::DrivenSkate, n: 3, m: 1, name: "driven-skate", peers: plain,
            about: "skate with drive torque τ and viscous damping c: f = (−c ẋ, −c ẏ, τ − c θ̇) (hand-written)",
            q0: [0.0, 0.0, 0.0], v0: [0.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Skate with smoothed dry friction along the blade (hand-written).
        FrictionSkate {
            ty: spark_runtime::fixtures::effects::FrictionSkate, n: 3, m: 1, name: "friction-skate", peers: plain,
            about: "skate with smoothed dry friction μ|ψ| along the blade, non-ideal constraint force (hand-written)",
            q0: [0.0, 0.0, 0.0], v0: [1.0, 0.0, 1.0], t_end: 10.0, h: 0.1,
        },
        /// Pendulum with a holonomic rod (hand-written, reports the drift of `g`).
        RodPendulumHand {
            ty: spark_runtime::fixtures::effects::RodPendulum, n: 2, m: 1, name: "rod-pendulum-hand", peers: plain,
            about: "pendulum with the rod ½(x² + y² − ℓ²) = 0 at velocity level, hand-written with its drift residual g",
            q0: [0.6, -0.8], v0: [0.8, 0.6], t_end: 10.0, h: 0.05,
        },
    ]
}

/// The events `kind` declares.
pub fn declared_events(kind: SystemKind) -> &'static [EventSpec] {
    struct Events;
    impl SystemVisitor for Events {
        type Output = &'static [EventSpec];
        fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
            self,
            _: &'static SystemEntry,
        ) -> &'static [EventSpec] {
            Sys::EVENTS
        }
    }
    visit_system(kind, Events)
}

/// The registered systems that declare at least one event.
pub fn systems_with_events() -> Vec<&'static str> {
    SystemKind::ALL.iter().filter(|k| !declared_events(**k).is_empty()).map(|k| k.key()).collect()
}
