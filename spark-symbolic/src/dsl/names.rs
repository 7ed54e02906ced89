//! Name rules of the DSL: reserved words, Rust keywords, and "did you mean"
//! suggestions for misspelt names.

use crate::spec::Func;

/// Rust keywords (strict, reserved and weak ones that matter in item position):
/// declared names become struct fields and locals of generated code.
const KEYWORDS: [&str; 52] = [
    "as", "break", "const", "continue", "crate", "else", "enum", "extern", "false", "fn", "for", "if", "impl", "in",
    "let", "loop", "match", "mod", "move", "mut", "pub", "ref", "return", "self", "Self", "static", "struct", "super",
    "trait", "true", "type", "unsafe", "use", "where", "while", "async", "await", "dyn", "abstract", "become", "box",
    "do", "final", "macro", "override", "priv", "typeof", "unsized", "virtual", "yield", "try", "gen",
];

/// Whether `name` is a Rust keyword.
pub(crate) fn is_keyword(name: &str) -> bool {
    KEYWORDS.contains(&name)
}

/// Rust primitive types that generated code names unqualified (`f64`
/// fields and locals, `usize` constants and indices, `bool` flags, `&str`
/// sources): a struct of one of these names shadows the primitive in its
/// module, and the generated code no longer compiles. The other primitives
/// (`f32`, `i32`, `char`, …) do not appear in it, so a struct may take them.
const PRIMITIVES_IN_GENERATED_CODE: [&str; 4] = ["bool", "f64", "str", "usize"];

/// Why `name` cannot name a struct (the declaration's or a scene's), if it
/// cannot. `kind` says which, as in "choose another {kind}".
pub(crate) fn struct_name_reason(name: &str, kind: &str) -> Option<String> {
    let bare = name.strip_prefix("r#").unwrap_or(name);
    let reason = if is_keyword(name) {
        format!("`{name}` is a Rust keyword")
    } else if PRIMITIVES_IN_GENERATED_CODE.contains(&bare) {
        format!("`{name}` names a Rust primitive type that the generated code uses")
    } else if bare.starts_with("__") {
        format!("`{name}`: names starting with `__` are reserved for generated code")
    } else {
        return None;
    };
    Some(format!("{reason}; choose another {kind}"))
}

/// Why `name` cannot be declared, if it cannot.
pub(crate) fn reserved_reason(name: &str) -> Option<String> {
    if name == "t" {
        return Some("`t` is reserved for the time".into());
    }
    if name == "pi" {
        return Some("`pi` is reserved for the constant π".into());
    }
    if name == "dot" {
        return Some("`dot` is reserved for velocities, as in `dot(x)`".into());
    }
    if let Some(f) = Func::from_name(name) {
        return Some(format!("`{}` is a function of the DSL", f.name()));
    }
    if name == "_" {
        return Some("`_` is not a name".into());
    }
    if name.starts_with("__") {
        return Some(format!("`{name}`: names starting with `__` are reserved for generated code"));
    }
    if name.starts_with("r#") {
        return Some(format!("`{name}`: raw identifiers are not supported"));
    }
    if is_keyword(name) {
        return Some(format!("`{name}` is a Rust keyword"));
    }
    None
}

/// Levenshtein distance over characters, ASCII case-insensitive.
pub(crate) fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().map(|c| c.to_ascii_lowercase()).collect();
    let b: Vec<char> = b.chars().map(|c| c.to_ascii_lowercase()).collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0; b.len() + 1];
    for (i, ca) in a.iter().enumerate() {
        cur[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let subst = prev[j] + usize::from(ca != cb);
            cur[j + 1] = subst.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

/// The candidate closest to `name`, if it is close enough to be a plausible
/// typo (or `name` is a prefix of it, as `coord` of `coordinates`).
pub(crate) fn nearest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    // One- and two-letter names are too short for an edit distance to mean
    // anything (`z` is one edit from every other letter).
    let len = name.chars().count();
    let limit = if len < 3 { 0 } else { (len / 3).max(1) };
    let mut best: Option<(usize, &str)> = None;
    for c in candidates {
        if c == name {
            continue;
        }
        let prefix = (name.len() >= 3 && c.starts_with(name)) || (c.len() >= 3 && name.starts_with(c));
        let d = if prefix { 1 } else { edit_distance(name, c) };
        if d <= limit && best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, c));
        }
    }
    best.map(|(_, c)| c)
}

/// Comma-separated list of backquoted names.
pub(crate) fn list(names: &[&str]) -> String {
    names.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        assert_eq!(edit_distance("theta", "thta"), 1);
        assert_eq!(edit_distance("", "abc"), 3);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("PI", "pi"), 0);
    }

    #[test]
    fn suggestions() {
        assert_eq!(nearest("thta", ["x", "theta", "t"]), Some("theta"));
        assert_eq!(nearest("coord", ["coordinates", "constants"]), Some("coordinates"));
        assert_eq!(nearest("zzzzzz", ["x", "theta"]), None);
        assert_eq!(nearest("constraint", ["constraints", "constants"]), Some("constraints"));
        assert_eq!(nearest("cosine", ["sin", "cos"]), Some("cos"));
        assert_eq!(nearest("z", ["x", "y"]), None);
        assert_eq!(nearest("PI", ["pi"]), Some("pi"));
    }

    #[test]
    fn reserved() {
        assert!(reserved_reason("t").is_some());
        assert!(reserved_reason("sin").is_some());
        assert!(reserved_reason("type").is_some());
        assert!(reserved_reason("__x").is_some());
        assert!(reserved_reason("theta").is_none());
    }

    #[test]
    fn struct_names() {
        for name in ["f64", "r#f64", "usize", "bool", "str", "struct", "__Sys"] {
            assert!(struct_name_reason(name, "struct name").is_some(), "{name}");
        }
        for name in ["Skate", "f32", "i32", "u8", "char", "info", "integrate", "r#Name"] {
            assert_eq!(struct_name_reason(name, "struct name"), None, "{name}");
        }
    }
}
