//! House rules that the compiler cannot check, kept by reading the source.
//!
//! Every `async fn` in `src/` and `drivers/*/src/` (outside `#[cfg(test)]` modules) says in its
//! doc comment whether it is cancel-safe: the `///` lines and attributes directly above it must
//! contain "cancel" (`Cancel-safe.`, `Cancel-safe: <why>`, `Not cancel-safe: <what a drop
//! leaves>`).

use std::path::{Path, PathBuf};

/// The `.rs` files under `dir`, sorted, recursively.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The source roots the rule covers: `src/` and every `drivers/<name>/src/`.
fn source_roots(root: &Path) -> Vec<PathBuf> {
    let mut roots = vec![root.join("src")];
    if let Ok(entries) = std::fs::read_dir(root.join("drivers")) {
        let mut drivers: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path().join("src")))
            .filter(|p| p.is_dir())
            .collect();
        drivers.sort();
        roots.extend(drivers);
    }
    roots
}

/// The name of the `async fn` declared on `line`, if one is.
fn async_fn_name(line: &str) -> Option<&str> {
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    let mut from = 0;
    while let Some(i) = line[from..].find("async").map(|i| i + from) {
        let tail = &line[i + "async".len()..];
        let starts_word = !line[..i].chars().next_back().is_some_and(ident);
        if starts_word && tail.starts_with(char::is_whitespace) {
            if let Some(decl) = tail.trim_start().strip_prefix("fn") {
                if decl.starts_with(char::is_whitespace) {
                    let decl = decl.trim_start();
                    return Some(&decl[..decl.find(|c| !ident(c)).unwrap_or(decl.len())]);
                }
            }
        }
        from = i + "async".len();
    }
    None
}

/// The files of the `#[cfg(test)] mod name;` modules that `file` (relative, `/` separated)
/// declares: `<dir>/name.rs` and `<dir>/name/mod.rs`.
fn test_module_files(file: &str, text: &str) -> Vec<String> {
    let dir = match file.rsplit_once('/') {
        Some((parent, "mod.rs" | "lib.rs" | "main.rs")) => parent.to_owned(),
        _ => file.trim_end_matches(".rs").to_owned(),
    };
    let mut out = Vec::new();
    let mut cfg_test = false;
    for t in text.lines().map(str::trim) {
        let decl = t.strip_prefix("pub ").unwrap_or(t).strip_prefix("mod ");
        match decl.and_then(|d| d.strip_suffix(';')) {
            Some(name) if cfg_test => {
                out.push(format!("{dir}/{name}.rs"));
                out.push(format!("{dir}/{name}/mod.rs"));
            }
            _ => {}
        }
        if !t.starts_with("///") && !t.is_empty() {
            cfg_test = t.starts_with("#[cfg(test)]");
        }
    }
    out
}

/// `[` minus `]` on a line (attributes may span lines).
fn bracket_balance(line: &str) -> i32 {
    line.chars().fold(0, |n, c| match c {
        '[' => n + 1,
        ']' => n - 1,
        _ => n,
    })
}

/// `{` minus `}` on a line (to skip a `#[cfg(test)]` module).
fn brace_balance(line: &str) -> i32 {
    line.chars().fold(0, |n, c| match c {
        '{' => n + 1,
        '}' => n - 1,
        _ => n,
    })
}

/// `file:line: name` of every `async fn` in `text` whose doc comment and attributes do not
/// mention cancel-safety; `#[cfg(test)]` modules are skipped.
fn undocumented_async_fns(file: &str, text: &str) -> Vec<String> {
    let mut missing = Vec::new();
    // the `///` lines and attributes above the current item
    let mut above = String::new();
    let mut open_attr = 0;
    let mut skip_depth: Option<i32> = None;
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        if let Some(depth) = skip_depth.as_mut() {
            *depth += brace_balance(t);
            if *depth <= 0 {
                skip_depth = None;
            }
            continue;
        }
        if open_attr > 0 {
            open_attr += bracket_balance(t);
            above.push_str(t);
            above.push('\n');
            continue;
        }
        if t.starts_with("///") || t.starts_with("#[") {
            if t.starts_with("#[") {
                open_attr = bracket_balance(t).max(0);
            }
            above.push_str(t);
            above.push('\n');
            continue;
        }
        if t.is_empty() || t.starts_with("//") {
            continue;
        }
        let is_mod = t.starts_with("mod ") || t.starts_with("pub mod ");
        if above.contains("#[cfg(test)]") && is_mod && t.ends_with('{') {
            skip_depth = Some(brace_balance(t));
        } else if let Some(name) = async_fn_name(t) {
            if !above.to_lowercase().contains("cancel") {
                missing.push(format!("{file}:{}: async fn {name}", n + 1));
            }
        }
        above.clear();
    }
    missing
}

#[test]
fn every_async_fn_says_whether_it_is_cancel_safe() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in source_roots(root) {
        rust_files(&dir, &mut files);
    }
    assert!(files.len() > 50, "found only {} source files", files.len());
    let sources: Vec<(String, String)> = files
        .iter()
        .map(|path| {
            let rel = path.strip_prefix(root).unwrap_or(path).to_string_lossy();
            let text = std::fs::read_to_string(path).unwrap();
            (rel.replace('\\', "/"), text)
        })
        .collect();
    let test_files: Vec<String> = sources
        .iter()
        .flat_map(|(rel, text)| test_module_files(rel, text))
        .collect();
    let mut missing = Vec::new();
    let mut checked = 0;
    for (rel, text) in &sources {
        if test_files.contains(rel) {
            continue;
        }
        checked += text.matches("async fn").count();
        missing.extend(undocumented_async_fns(rel, text));
    }
    assert!(
        checked > 100,
        "found only {checked} async fns: is the walk broken?"
    );
    assert!(
        missing.is_empty(),
        "{} async fn(s) whose doc does not say whether they are cancel-safe \
         (add `Cancel-safe: <why>` or `Not cancel-safe: <what a drop leaves>`):\n{}",
        missing.len(),
        missing.join("\n")
    );
}

#[test]
fn the_cancel_doc_check_reads_docs_attributes_and_skips_tests() {
    let text = "\
/// Does a thing.
async fn bare() {}

/// Does a thing. Cancel-safe: no state.
pub async fn documented() {}

/// Does a thing.
#[utoipa::path(get, path = \"/x\",
    responses((status = 200, description = \"[ok]\")))]
/// Not cancel-safe: a drop leaves half a line.
pub(crate) async fn multi_line_attribute() {}

#[async_trait]
impl T for U {
    // a plain comment does not count
    async fn in_impl(&self) {}
}

#[cfg(test)]
mod tests {
    async fn helper() {}
}
";
    let missing = undocumented_async_fns("x.rs", text);
    assert_eq!(
        missing,
        vec!["x.rs:2: async fn bare", "x.rs:16: async fn in_impl"]
    );
    let declared = "#[cfg(test)]\nmod tests;\nmod real;\n";
    assert_eq!(
        test_module_files("src/store/mod.rs", declared),
        vec!["src/store/tests.rs", "src/store/tests/mod.rs"]
    );
    assert_eq!(
        test_module_files("src/sim.rs", declared),
        vec!["src/sim/tests.rs", "src/sim/tests/mod.rs"]
    );
}
