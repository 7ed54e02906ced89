//! `spark list`: the catalogue as a table or as JSON.

use crate::catalog::{declared_events, entries, SystemEntry, SystemInfo, SystemKind, MAX_DISPATCH_STAGES};
use clap::Args;
use spark_runtime::Direction;
use spark_runtime::Method;
use std::collections::BTreeMap;

/// How `k` depends on `t` and `v`, in a few words (`none`, `linear`,
/// `affine`, `nonlinear`, with `, t` when rheonomic).
fn constraint_text(e: &SystemEntry) -> String {
    use spark_runtime::ConstraintForm;
    let form = match e.structure.constraint_form {
        ConstraintForm::None => "none",
        ConstraintForm::Linear => "linear",
        ConstraintForm::Affine => "affine",
        ConstraintForm::Nonlinear => "nonlinear",
    };
    if e.structure.constraints_autonomous || e.m == 0 {
        form.to_string()
    } else {
        format!("{form}, k(t)")
    }
}

/// The table `spark list` prints: one row per system with `N`, `M`, the
/// constraint form, structure facts and effects, then a description, the
/// parameters with defaults and the default initial state of each.
pub fn list_table() -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let w = entries().iter().map(|e| e.name.len()).max().unwrap_or(4);
    let _ = writeln!(
        s,
        "{:<w$} {:>2} {:>2}  {:<13} {:<4} {:<5} {:<4} {:<20} {:>5}  paper",
        "name", "N", "M", "constraints", "L(t)", "mass", "sep.", "effects", "ops"
    );
    for e in entries() {
        let line = format!(
            "{:<w$} {:>2} {:>2}  {:<13} {:<4} {:<5} {:<4} {:<20} {:>5}  {}",
            e.name,
            e.n,
            e.m,
            constraint_text(e),
            if e.structure.lagrangian_autonomous { "no" } else { "yes" },
            if e.structure.constant_mass_matrix { "const" } else { "q,v" },
            match (e.structure.separable, e.constant_stiffness, e.diagonal_stiffness) {
                (true, true, _) => "quad",
                (true, false, true) => "diag",
                (true, false, false) => "yes",
                (false, _, _) => "no",
            },
            e.effects_text(),
            if e.operations.stage_jacobians == 0 {
                "hand".to_string()
            } else {
                e.operations.stage_jacobians.to_string()
            },
            if e.paper { "yes" } else { "" },
        );
        let _ = writeln!(s, "{}", line.trim_end());
    }
    let _ = writeln!(
        s,
        "\n(L(t): Lagrangian depends on t; mass: ∇²_vv L constant or not; sep.: L = T(v) − U(q), \
         `quad` with U quadratic (a constant stiffness), `diag` with U a sum of functions of one \
         coordinate each (a diagonal stiffness); \
         ops: operations of the generated stage_jacobians, `hand` for hand-written types)\n"
    );
    for e in entries() {
        let _ = writeln!(s, "{} — {} ({})", e.name, e.description, e.path);
        let _ = writeln!(s, "    coordinates [{}]", e.coordinates.join(", "));
        let params = e.default_parameters();
        if !params.is_empty() {
            let p: Vec<String> = params.iter().map(|(n, v)| format!("{n} = {v}")).collect();
            let _ = writeln!(s, "    parameters: {}", p.join(", "));
        }
        let events = declared_events(e.kind);
        if !events.is_empty() {
            let each: Vec<String> = events
                .iter()
                .map(|ev| {
                    let direction = match ev.direction {
                        Direction::Rising => "rising",
                        Direction::Falling => "falling",
                        Direction::Both => "either way",
                    };
                    let terminal = if ev.terminal { ", terminal" } else { "" };
                    format!("{} ({direction}{terminal})", ev.name)
                })
                .collect();
            let _ = writeln!(s, "    events (spark run --events, spark section --event): {}", each.join(", "));
        }
        let _ = writeln!(
            s,
            "    defaults: t0 = {}, q0 = {:?}, v0 = {:?}, h = {}, t_end = {}",
            e.t0, e.q0, e.v0, e.h, e.t_end
        );
    }
    s
}

/// What `spark list --json` prints: every system with its parameter
/// defaults and the orders of the methods on it, the methods, and the most
/// stages the dispatch compiles.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Listing {
    /// The systems, in catalogue order.
    pub systems: Vec<ListedSystem>,
    /// The methods, in [`Method::ALL`] order.
    pub methods: Vec<ListedMethod>,
    /// The most stages `spark` runs a method with.
    pub max_stages: usize,
}

/// A system of [`Listing`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct ListedSystem {
    /// The entry and its parameter defaults.
    #[serde(flatten)]
    pub info: SystemInfo,
    /// The global order of each method (by key) with each stage count it
    /// runs with on this system, as the drivers take it
    /// ([`Method::order_for`]): the figures the text listing prints, its
    /// caveat included (the modified Lobatto IIIA-B is of order 1 where
    /// the mass matrix is not constant or `L` not separable).
    pub orders: BTreeMap<&'static str, BTreeMap<usize, usize>>,
}

/// A method of [`Listing`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct ListedMethod {
    /// The name `--method` takes.
    pub key: &'static str,
    /// The human-readable name.
    pub name: &'static str,
    /// The fewest stages.
    pub min_stages: usize,
    /// The most stages `spark` runs it with.
    pub max_stages: usize,
    /// The order with each stage count on the systems the paper states it
    /// for ([`Method::order`]); a system's `orders` has it per system.
    pub orders: BTreeMap<usize, usize>,
}

/// The stage counts `spark` runs `m` with.
fn stage_counts(m: Method) -> std::ops::RangeInclusive<usize> {
    let (lo, hi) = m.stage_range();
    lo..=hi.min(MAX_DISPATCH_STAGES)
}

/// Every entry with its parameter defaults and method orders, and the
/// methods, for `spark list --json`.
pub fn list_json() -> Listing {
    let systems = SystemKind::ALL
        .iter()
        .map(|k| {
            let info = k.info();
            let orders = Method::ALL
                .iter()
                .map(|&m| (m.key(), stage_counts(m).map(|s| (s, m.order_for(s, &info.entry.structure))).collect()))
                .collect();
            ListedSystem { info, orders }
        })
        .collect();
    let methods = Method::ALL
        .iter()
        .map(|&m| ListedMethod {
            key: m.key(),
            name: m.name(),
            min_stages: *stage_counts(m).start(),
            max_stages: *stage_counts(m).end(),
            orders: stage_counts(m).map(|s| (s, m.order(s))).collect(),
        })
        .collect();
    Listing { systems, methods, max_stages: MAX_DISPATCH_STAGES }
}

#[derive(Args, Debug)]
/// Arguments of `spark list`.
pub struct ListArgs {
    /// Print the systems as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// `spark list`: the systems and the methods, as a table or as JSON.
pub fn list(a: ListArgs) -> Result<String, String> {
    use std::fmt::Write as _;
    let mut s = String::new();
    if a.json {
        let text = serde_json::to_string_pretty(&list_json()).map_err(|e| e.to_string())?;
        return Ok(text + "\n");
    }
    let _ = writeln!(s, "Systems (use the name with `spark run NAME` or `--system NAME`):\n");
    s.push_str(&list_table());
    let _ = writeln!(s, "\nMethods (use the name with --method, the stage count with --stages):\n");
    for m in Method::ALL {
        let key = m.key();
        let (lo, hi) = (*stage_counts(m).start(), *stage_counts(m).end());
        let stages = if lo == hi { format!("s = {lo}") } else { format!("s = {lo}..{hi}") };
        let order = if lo == hi { format!("order {}", m.order(lo)) } else { "order ".to_string() + &order_formula(m) };
        let caveat = if lo == hi { order_caveat(m, lo) } else { String::new() };
        let _ = writeln!(s, "  {key:<24} {:<42} {stages:<10} {order}{caveat}", m.name());
    }
    Ok(s)
}

/// What the order `spark list` prints for `m` with `s` stages depends on,
/// when it is not the same on every system: the modified Lobatto IIIA-B is
/// of order 2 with a constant mass matrix and separable `L`
/// ([`Method::order_for`]) and of order 1 otherwise, so the listing names
/// the systems where it is lower, by the same rule the drivers use.
pub fn order_caveat(m: Method, s: usize) -> String {
    let order = m.order(s);
    let mut lower: std::collections::BTreeMap<usize, Vec<&str>> = Default::default();
    for e in entries() {
        let here = m.order_for(s, &e.structure);
        if here != order {
            lower.entry(here).or_default().push(e.name);
        }
    }
    let others: Vec<String> =
        lower.iter().map(|(here, names)| format!("order {here} on {}", names.join(", "))).collect();
    if others.is_empty() {
        return String::new();
    }
    format!(" with a constant mass matrix and separable L; {}", others.join("; "))
}

/// The order of `m` as a formula in `s`.
fn order_formula(m: Method) -> String {
    match m {
        Method::Gauss => "2s".into(),
        _ => "2s − 2".into(),
    }
}
