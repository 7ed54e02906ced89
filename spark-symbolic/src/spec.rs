//! The parsed declaration handed from `spark-macros` (the parser) to the
//! engine: names, parameters and source expressions, each with the span of
//! the token it came from so that every error points at the user's code.
//!
//! This is the contract between the two crates: the parser resolves every
//! identifier (coordinate, velocity, parameter, constant, time, `pi`) and
//! checks function names and arities; the engine does everything after that
//! (differentiation, structure analysis, code emission) and reports semantic
//! errors (e.g. a holonomic constraint) as [`SpecError`] with a span.

use proc_macro2::{Span, TokenStream};

/// Elementary functions of the DSL.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Func {
    /// `sqrt(x)`.
    Sqrt,
    /// `exp(x)`.
    Exp,
    /// `ln(x)`.
    Ln,
    /// `sin(x)`.
    Sin,
    /// `cos(x)`.
    Cos,
    /// `tan(x)`.
    Tan,
    /// `sinh(x)`.
    Sinh,
    /// `cosh(x)`.
    Cosh,
    /// `tanh(x)`.
    Tanh,
    /// `atan2(y, x)`.
    Atan2,
}

impl Func {
    /// Looks a DSL function name up.
    pub fn from_name(name: &str) -> Option<Func> {
        Some(match name {
            "sqrt" => Func::Sqrt,
            "exp" => Func::Exp,
            "ln" => Func::Ln,
            "sin" => Func::Sin,
            "cos" => Func::Cos,
            "tan" => Func::Tan,
            "sinh" => Func::Sinh,
            "cosh" => Func::Cosh,
            "tanh" => Func::Tanh,
            "atan2" => Func::Atan2,
            _ => return None,
        })
    }
    /// The DSL (and neutral-text) name.
    pub fn name(self) -> &'static str {
        match self {
            Func::Sqrt => "sqrt",
            Func::Exp => "exp",
            Func::Ln => "ln",
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Sinh => "sinh",
            Func::Cosh => "cosh",
            Func::Tanh => "tanh",
            Func::Atan2 => "atan2",
        }
    }
    /// Number of arguments.
    pub fn arity(self) -> usize {
        match self {
            Func::Atan2 => 2,
            _ => 1,
        }
    }
    /// Every function, for error messages and tests.
    pub const ALL: [Func; 10] = [
        Func::Sqrt,
        Func::Exp,
        Func::Ln,
        Func::Sin,
        Func::Cos,
        Func::Tan,
        Func::Sinh,
        Func::Cosh,
        Func::Tanh,
        Func::Atan2,
    ];
}

/// Binary operators of the DSL.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinOp {
    /// `a + b`.
    Add,
    /// `a - b`.
    Sub,
    /// `a * b`.
    Mul,
    /// `a / b`.
    Div,
    /// `a ^ b` (integer or real power).
    Pow,
}

/// A source expression as the user wrote it, with identifiers resolved.
#[derive(Clone, Debug)]
pub enum SrcExpr {
    /// A numeric literal.
    Num(f64, Span),
    /// The time `t`.
    Time(Span),
    /// `pi`.
    Pi(Span),
    /// Coordinate `q_i` (index into [`SystemSpec::coordinates`]).
    Coord(usize, Span),
    /// Velocity `v_i = dot(q_i)`.
    Velocity(usize, Span),
    /// Runtime parameter (index into [`SystemSpec::parameters`]).
    Param(usize, Span),
    /// Named constant (index into [`SystemSpec::constants`]).
    Const(usize, Span),
    /// Unary minus.
    Neg(Box<SrcExpr>, Span),
    /// Binary operation.
    Binary(BinOp, Box<SrcExpr>, Box<SrcExpr>, Span),
    /// Function call with the right number of arguments.
    Call(Func, Vec<SrcExpr>, Span),
    /// Multiplier `ψ_j` of constraint `j` (index into
    /// [`SystemSpec::constraints`]); only in [`SystemSpec::nonideal_force`].
    Multiplier(usize, Span),
}

impl SrcExpr {
    /// The span of the token (or operator) this node came from.
    pub fn span(&self) -> Span {
        match self {
            SrcExpr::Num(_, s)
            | SrcExpr::Time(s)
            | SrcExpr::Pi(s)
            | SrcExpr::Coord(_, s)
            | SrcExpr::Velocity(_, s)
            | SrcExpr::Param(_, s)
            | SrcExpr::Const(_, s)
            | SrcExpr::Neg(_, s)
            | SrcExpr::Binary(_, _, _, s)
            | SrcExpr::Call(_, _, s)
            | SrcExpr::Multiplier(_, s) => *s,
        }
    }
}

/// A name with the span where it was declared.
#[derive(Clone, Debug)]
pub struct Named {
    /// The identifier as written.
    pub name: String,
    /// Where it was declared.
    pub span: Span,
}

/// A runtime parameter: a public `f64` field with a default value.
#[derive(Clone, Debug)]
pub struct Parameter {
    /// Name and declaration site.
    pub name: Named,
    /// Default value.
    pub default: f64,
}

/// A named constant, folded into the expressions at compile time. Its value
/// may refer to earlier constants and to numbers, never to coordinates,
/// velocities, `t` or parameters (the parser checks this).
#[derive(Clone, Debug)]
pub struct Constant {
    /// Name and declaration site.
    pub name: Named,
    /// Value expression.
    pub value: SrcExpr,
}

/// One constraint `k_j(t,q,v)` as written, with its span.
#[derive(Clone, Debug)]
pub struct ConstraintSpec {
    /// The expression: `k(t,q,v)`, or `g(t,q)` for a holonomic row.
    pub expr: SrcExpr,
    /// Span covering the whole constraint (for "this constraint is holonomic").
    pub span: Span,
    /// The row is a holonomic constraint `g = 0` (a `holonomic` effect):
    /// [`ConstraintSpec::expr`] is `g(t,q)`, and the model imposes its
    /// velocity-level form `k = g_t + g_q·v` (differentiated on the graph)
    /// and reports the drift of `g`. `false` for a constraint written at
    /// velocity level.
    pub holonomic: bool,
}

/// Which zero crossings of an event function count (mirrors
/// `spark_runtime::Direction`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EventDirection {
    /// From negative to non-negative (`rising(expr)`).
    Rising,
    /// From positive to non-positive (`falling(expr)`).
    Falling,
    /// Both (`expr` or `crossing(expr)`).
    Both,
}

/// One event `name: [rising|falling|crossing](g(t,q,v)) [terminal]`.
#[derive(Clone, Debug)]
pub struct EventDecl {
    /// Name and declaration site.
    pub name: Named,
    /// `g(t,q,v)`.
    pub expr: SrcExpr,
    /// Which crossings count.
    pub direction: EventDirection,
    /// Whether the first crossing ends the run.
    pub terminal: bool,
}

/// A whole declaration.
#[derive(Clone, Debug)]
pub struct SystemSpec {
    /// Outer attributes (doc comments, derives) passed through to the struct.
    pub attrs: TokenStream,
    /// Visibility of the struct (`pub`, `pub(crate)`, or empty).
    pub vis: TokenStream,
    /// Type name.
    pub name: proc_macro2::Ident,
    /// Generalized coordinates, at least one.
    pub coordinates: Vec<Named>,
    /// Runtime parameters.
    pub parameters: Vec<Parameter>,
    /// Named constants.
    pub constants: Vec<Constant>,
    /// `L(t,q,v)`.
    pub lagrangian: SrcExpr,
    /// `k(t,q,v)`, possibly empty.
    pub constraints: Vec<ConstraintSpec>,
    /// External generalized force `f(t,q,v)`: empty when the system has
    /// none, else one entry per coordinate (`None` = zero component). Never
    /// contains [`SrcExpr::Multiplier`].
    pub external_force: Vec<Option<SrcExpr>>,
    /// Non-ideal constraint force `N(t,q,v,ψ)`: empty when absent, else one
    /// entry per coordinate (`None` = zero component); may use
    /// [`SrcExpr::Multiplier`].
    pub nonideal_force: Vec<Option<SrcExpr>>,
    /// Events `g(t,q,v)` whose zeros the driver locates; empty when none.
    pub events: Vec<EventDecl>,
    /// Path under which generated code finds the runtime
    /// (`::spark_runtime` unless the caller says otherwise).
    pub runtime_path: TokenStream,
}

impl SystemSpec {
    /// Traits the user already derives on the struct (`#[derive(...)]` in
    /// [`SystemSpec::attrs`]), so that the generated derives do not clash.
    pub fn user_derives(&self) -> Vec<proc_macro2::Ident> {
        let mut out = Vec::new();
        let Ok(attrs) = syn::parse::Parser::parse2(syn::Attribute::parse_outer, self.attrs.clone()) else {
            return out;
        };
        for a in attrs.iter().filter(|a| a.path().is_ident("derive")) {
            let _ = a.parse_nested_meta(|m| {
                if let Some(seg) = m.path.segments.last() {
                    out.push(seg.ident.clone());
                }
                Ok(())
            });
        }
        out
    }
}

/// One effect of an `effects:` section, as parsed (see [`crate::scenes`]).
#[derive(Clone, Debug)]
pub enum Effect {
    /// `potential(U)`: `U(t,q,v)`, subtracted from `L`.
    Potential(SrcExpr),
    /// `constraint(k)`: an extra velocity-level constraint, with the span of
    /// its argument.
    Constraint(SrcExpr, Span),
    /// `holonomic(g)`: `g(t,q) = 0`, imposed as `k = g_t + g_q·v`.
    Holonomic(SrcExpr, Span),
    /// `force { … }`: external force components by coordinate.
    Force(Vec<Option<SrcExpr>>),
    /// `nonideal { … }`: non-ideal constraint force components. The
    /// multiplier of constraint effect `e` carries the provisional index
    /// `M_base + e` until a scene fixes the constraint order.
    Nonideal(Vec<Option<SrcExpr>>),
    /// `event(…)`: an event named like the effect.
    Event(EventDecl),
}

/// A named effect.
#[derive(Clone, Debug)]
pub struct EffectDecl {
    /// The effect's name as written.
    pub name: proc_macro2::Ident,
    /// What it adds.
    pub effect: Effect,
}

/// One scene `Name = [effect, …]`: a type generated from the base
/// declaration plus the listed effects.
#[derive(Clone, Debug)]
pub struct SceneDecl {
    /// The scene's type name.
    pub name: proc_macro2::Ident,
    /// The selected effects, in the scene's order: indices into
    /// [`Declaration::effects`], with the token that names each.
    pub effects: Vec<(usize, proc_macro2::Ident)>,
}

/// A whole `nonholonomic_system!` body: the base declaration and, when it
/// has `effects:` and `scenes:`, those (both empty otherwise).
#[derive(Clone, Debug)]
pub struct Declaration {
    /// The declaration without its effects and scenes.
    pub base: SystemSpec,
    /// The declared effects.
    pub effects: Vec<EffectDecl>,
    /// The declared scenes; empty for a plain declaration.
    pub scenes: Vec<SceneDecl>,
}

/// A semantic error found by the engine, with the span to point at.
#[derive(Clone, Debug)]
pub struct SpecError {
    /// Where.
    pub span: Span,
    /// What is wrong and what to write instead.
    pub message: String,
}

impl SpecError {
    /// The error as a `compile_error!` invocation at its span, its message
    /// as [`SpecError::shown_message`] gives it.
    pub fn to_compile_error(&self) -> TokenStream {
        let msg = self.shown_message();
        let msg = msg.as_ref();
        quote::quote_spanned!(self.span=> ::core::compile_error!(#msg);)
    }

    /// The message as shown to the user (the macro's `compile_error!`,
    /// `spark.compile`'s `DslError`): each name it quotes is cut by
    /// [`bound_long_words`], so a name of millions of characters does not
    /// fill the message.
    pub fn shown_message(&self) -> std::borrow::Cow<'_, str> {
        bound_long_words(&self.message)
    }
}

/// The most characters of one word (a run of letters, digits and `_`: an
/// identifier, a number) that an error message quotes whole; a longer one is
/// shown as its first [`WORD_EXCERPT`] characters and `… (N characters)`.
pub const MAX_QUOTED_WORD: usize = 64;

/// The characters of a word longer than [`MAX_QUOTED_WORD`] that a message
/// keeps.
pub const WORD_EXCERPT: usize = 40;

/// `message` with each word (a run of letters, digits and `_`) longer than
/// [`MAX_QUOTED_WORD`] characters replaced by its first [`WORD_EXCERPT`]
/// characters and `… (N characters)`; unchanged (borrowed) without one.
pub fn bound_long_words(message: &str) -> std::borrow::Cow<'_, str> {
    let is_word = |c: char| c.is_alphanumeric() || c == '_';
    let mut out = String::new();
    // The bytes of `message` copied to `out` so far, and the current word:
    // its start (a byte offset) and its length in characters.
    let mut copied = 0;
    let mut word: Option<(usize, usize)> = None;
    let mut cut = false;
    let mut flush = |out: &mut String, copied: &mut usize, start: usize, chars: usize, end: usize| {
        if chars > MAX_QUOTED_WORD {
            let keep = message[start..end].char_indices().nth(WORD_EXCERPT).map_or(end, |(i, _)| start + i);
            out.push_str(&message[*copied..keep]);
            out.push_str(&format!("… ({chars} characters)"));
            *copied = end;
            cut = true;
        }
    };
    for (i, c) in message.char_indices() {
        match (is_word(c), word) {
            (true, Some((start, chars))) => word = Some((start, chars + 1)),
            (true, None) => word = Some((i, 1)),
            (false, Some((start, chars))) => {
                flush(&mut out, &mut copied, start, chars, i);
                word = None;
            }
            (false, None) => {}
        }
    }
    if let Some((start, chars)) = word {
        flush(&mut out, &mut copied, start, chars, message.len());
    }
    if !cut {
        return std::borrow::Cow::Borrowed(message);
    }
    out.push_str(&message[copied..]);
    std::borrow::Cow::Owned(out)
}
