//! Symbolic engine of spark: the DSL parser, a hash-consed expression graph,
//! exact differentiation, simplification, common-subexpression elimination,
//! structure analysis and Rust code emission.
//!
//! It is an ordinary library (no proc-macro context needed) so that it can be
//! tested, fuzzed and benchmarked on its own; `spark-macros` only calls
//! [`expand`].
//!
//! Pipeline: [`dsl::parse_declaration`] → [`scenes::desugar`] (one
//! [`SystemSpec`] per generated type) → [`dsl::validate()`] →
//! [`model::Model::build`] (lowering, derivatives, structure) →
//! [`codegen::generate_items`] (CSE and emission through [`emit`]).
#![warn(missing_docs)]

pub mod codegen;
pub mod diff;
pub mod dsl;
pub mod emit;
pub mod graph;
pub mod lower;
pub mod model;
pub mod nonlinearity;
pub mod pretty;
pub mod scenes;
pub mod simplify;
pub mod source;
pub mod spec;

pub use codegen::Operations;
pub use model::{ConstraintForm, Structure};
pub use spec::{
    BinOp, Constant, ConstraintSpec, Declaration, Effect, EffectDecl, EventDecl, EventDirection, Func, Named,
    Parameter, SceneDecl, SpecError, SrcExpr, SystemSpec,
};

use proc_macro2::TokenStream;

/// What the engine proved and measured about a declaration, for tools that
/// want the facts without the code.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Analysis {
    /// Number of coordinates `N`.
    pub n: usize,
    /// Number of constraints `M`.
    pub m: usize,
    /// Structure facts (autonomy, constant mass matrix, separability, constraint form).
    pub structure: Structure,
    /// Operation counts of the generated code.
    pub operations: Operations,
    /// Neutral S-expression text of `L`.
    pub lagrangian_source: String,
    /// Neutral S-expression text of each `k_j`.
    pub constraint_sources: Vec<String>,
}

/// Builds the symbolic model of `spec` and reports its structure and the
/// operation counts the generated code will have.
pub fn analyze(spec: &SystemSpec) -> Result<Analysis, SpecError> {
    let mut model = model::Model::build(spec)?;
    let params: Vec<proc_macro2::Ident> =
        spec.parameters.iter().map(|p| proc_macro2::Ident::new(&p.name.name, p.name.span)).collect();
    let operations = codegen::count_operations(&mut model, &params);
    // Emission adds nodes too (the prefixes of long products).
    model::check_graph_size(spec, &model.graph)?;
    Ok(Analysis {
        n: model.n,
        m: model.m,
        structure: model.structure,
        operations,
        lagrangian_source: source::sexpr(spec, &spec.lagrangian),
        constraint_sources: source::constraint_sexprs(spec, &model),
    })
}

/// Generates the struct, its `Default`, inherent items and the
/// `NonholonomicSystem` implementation for a parsed declaration.
///
/// Declarations whose accelerations are undetermined everywhere (see
/// [`model::Model::check_determined`]) are rejected.
pub fn generate(spec: &SystemSpec) -> Result<TokenStream, SpecError> {
    generate_checked(spec, true)
}

/// [`generate`], with the structural-singularity check optional: the base
/// declaration of a system with scenes may leave a coordinate to be fixed
/// by a scene's constraint effect, so only the scenes are checked.
pub(crate) fn generate_checked(spec: &SystemSpec, check: bool) -> Result<TokenStream, SpecError> {
    dsl::validate(spec)?;
    let mut model = model::Model::build(spec)?;
    if check {
        model.check_determined(spec)?;
    }
    let items = codegen::generate_items(spec, &mut model).0;
    // Emission adds nodes too (the prefixes of long products).
    model::check_graph_size(spec, &model.graph)?;
    Ok(items)
}

/// The whole macro: DSL tokens in, generated items (or a `compile_error!`
/// pointing at the offending token) out. Never panics.
pub fn expand(input: TokenStream) -> TokenStream {
    expand_all(input).unwrap_or_else(|error| error.to_compile_error())
}

/// Parses, desugars the scenes and generates every resulting type. The
/// base declaration of a system with scenes may leave a coordinate to be
/// fixed by a scene's constraint effect, so only the scenes are checked for
/// determined accelerations.
fn expand_all(input: TokenStream) -> Result<TokenStream, SpecError> {
    let declaration = dsl::parse_declaration(input)?;
    let base_is_checked = declaration.scenes.is_empty();
    let mut out = TokenStream::new();
    for (i, spec) in scenes::desugar(declaration)?.iter().enumerate() {
        out.extend(generate_checked(spec, i > 0 || base_is_checked)?);
    }
    Ok(out)
}
