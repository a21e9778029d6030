//! The documentation resolves and matches the code: every relative link and `#anchor` of
//! README.md, ARCHITECTURE.md and docs/*.md leads somewhere, every repository path,
//! `file.rs::test` and `module::item` of this crate they name exists, docs/cli.md lists exactly the flags `cellcal … --help` shows,
//! docs/rest-api.md exactly the routes of the OpenAPI document, docs/configuration.md every key
//! of the shipped configuration files, and the README stays short.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use crate::common::cellcal_process;

/// The repository root.
fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The checked Markdown files: README.md, ARCHITECTURE.md and every docs/*.md, sorted.
fn doc_files() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md"), root().join("ARCHITECTURE.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "md"))
                .collect()
        })
        .unwrap_or_default();
    docs.sort();
    files.extend(docs);
    files
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn rel(path: &Path) -> String {
    path.strip_prefix(root())
        .unwrap_or(path)
        .display()
        .to_string()
}

/// The lines of `text` outside fenced code blocks, with their 1-based numbers.
fn prose_lines(text: &str) -> Vec<(usize, &str)> {
    let mut fenced = false;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            out.push((i + 1, line));
        }
    }
    out
}

/// The inline code spans of one line (between single backticks).
fn code_spans(line: &str) -> Vec<&str> {
    line.split('`').skip(1).step_by(2).collect()
}

/// `line` with its code spans blanked, so nothing inside backticks reads as a link.
fn without_code(line: &str) -> String {
    line.split('`')
        .enumerate()
        .map(|(i, part)| if i % 2 == 0 { part } else { "" })
        .collect::<Vec<_>>()
        .join("``")
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .collect()
}

/// Every heading anchor of a Markdown text (a repeated heading gets `-1`, `-2`, … as on GitHub).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    for (_, line) in prose_lines(text) {
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if hashes == 0 || hashes > 6 || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slug(&line[hashes..]);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        });
        *n += 1;
    }
    out
}

/// The targets of the inline links `[text](target)` and images of one line (code spans excluded).
fn link_targets(line: &str) -> Vec<String> {
    let line = without_code(line);
    let mut out = Vec::new();
    let mut rest = line.as_str();
    while let Some(i) = rest.find("](") {
        let tail = &rest[i + 2..];
        let Some(end) = tail.find(')') else { break };
        out.push(tail[..end].trim().to_owned());
        rest = &tail[end..];
    }
    out
}

/// Why the link `target` in the doc `from` does not resolve, if it does not.
fn broken_link(from: &Path, target: &str) -> Option<String> {
    if target.contains("://") || target.starts_with("mailto:") {
        return None;
    }
    let (path, anchor) = target.split_once('#').unwrap_or((target, ""));
    let file = if path.is_empty() {
        from.to_path_buf()
    } else {
        from.parent().unwrap_or(root()).join(path)
    };
    if !file.exists() {
        return Some(format!("{target}: no such file"));
    }
    if anchor.is_empty() {
        return None;
    }
    if file.extension().is_none_or(|x| x != "md") {
        return Some(format!(
            "{target}: an anchor into a file that is not Markdown"
        ));
    }
    (!anchors(&read(&file)).contains(anchor)).then(|| {
        format!(
            "{target}: no heading with anchor #{anchor} in {}",
            rel(&file)
        )
    })
}

/// Every broken relative link or missing anchor of `files`, as `file:line: why`.
fn broken_links(files: &[PathBuf]) -> Vec<String> {
    let mut out = Vec::new();
    for file in files {
        let text = read(file);
        for (n, line) in prose_lines(&text) {
            for target in link_targets(line) {
                if let Some(why) = broken_link(file, &target) {
                    out.push(format!("{}:{n}: {why}", rel(file)));
                }
            }
        }
    }
    out
}

/// Repository folders whose paths the docs name in backticks.
const PATH_PREFIXES: [&str; 8] = [
    "src/", "tests/", "config/", "web/", "deploy/", "drivers/", "docs/", "benches/",
];

/// `a/{b,c}.rs` → `a/b.rs`, `a/c.rs` (one brace group).
fn expand_braces(path: &str) -> Vec<String> {
    match (path.find('{'), path.find('}')) {
        (Some(open), Some(close)) if open < close => path[open + 1..close]
            .split(',')
            .map(|alt| format!("{}{}{}", &path[..open], alt, &path[close + 1..]))
            .collect(),
        _ => vec![path.to_owned()],
    }
}

/// The repository files whose path ends with `/name` (or is `name`), for `file.rs::test` cited
/// without its folder.
fn files_named(name: &str) -> Vec<PathBuf> {
    fn walk(dir: &Path, name: &str, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for p in entries.filter_map(|e| e.ok().map(|e| e.path())) {
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n != "target" && n != ".git") {
                    walk(&p, name, out);
                }
            } else if p.to_string_lossy().ends_with(&format!("/{name}")) {
                out.push(p);
            }
        }
    }
    let mut out = Vec::new();
    for dir in ["src", "tests", "drivers", "benches"] {
        walk(&root().join(dir), name, &mut out);
    }
    out
}

/// Why the backticked reference `span` does not resolve, if it names a repository path or a
/// `file.rs::test` and does not.
fn broken_reference(span: &str) -> Option<String> {
    let token = span.split_whitespace().next().unwrap_or("");
    if let Some((file, name)) = token.split_once(".rs::") {
        let name = name.trim_end_matches(|c: char| !c.is_alphanumeric() && c != '_');
        let is_test_ref = !file.is_empty()
            && !name.is_empty()
            && name.chars().all(|c| c.is_alphanumeric() || c == '_')
            && file
                .chars()
                .all(|c| c.is_alphanumeric() || "_/-.".contains(c));
        if !is_test_ref {
            return None;
        }
        let file = format!("{file}.rs");
        let candidates = if root().join(&file).is_file() {
            vec![root().join(&file)]
        } else {
            files_named(&file)
        };
        if candidates.is_empty() {
            return Some(format!("`{span}`: no file {file}"));
        }
        let found = candidates
            .iter()
            .any(|f| read(f).contains(&format!("fn {name}(")));
        return (!found).then(|| format!("`{span}`: no fn {name} in {file}"));
    }
    if let Some(why) = broken_module_path(token) {
        return Some(format!("`{span}`: {why}"));
    }
    if !PATH_PREFIXES.iter().any(|p| token.starts_with(p)) {
        return None;
    }
    let path = token
        .trim_end_matches([':', ',', '.', ';', ')'])
        .split(['#', ':'])
        .next()
        .unwrap_or("");
    for path in expand_braces(path) {
        // a pattern (`tests/it/browser*.rs`, `src/…`): its folder must exist
        let fixed = match path.find(['*', '…', '<']) {
            Some(i) => path[..i]
                .rsplit_once('/')
                .map_or("", |(dir, _)| dir)
                .to_owned(),
            None => path.clone(),
        };
        if !root().join(&fixed).exists() {
            return Some(format!("`{span}`: {fixed} does not exist"));
        }
    }
    None
}

/// Why `module::…::item` (a path into this crate's `src/`, lower case) does not resolve: each
/// module is a folder or file under `src/`, and the last name is declared in the last one.
fn broken_module_path(token: &str) -> Option<String> {
    let segments: Vec<&str> = token.split("::").collect();
    let lower = |s: &&str| !s.is_empty() && s.chars().all(|c| c.is_ascii_lowercase() || c == '_');
    if segments.len() < 2 || !segments.iter().all(lower) {
        return None;
    }
    let src = root().join("src");
    let first = segments[0];
    if !src.join(first).is_dir() && !src.join(format!("{first}.rs")).is_file() {
        return None; // not one of ours (a driver crate, `std::…`)
    }
    let (modules, item) = segments.split_at(segments.len() - 1);
    let mut at = src;
    for m in modules {
        if at.is_file() {
            break; // an inline module of that file
        }
        at = if at.join(m).is_dir() {
            at.join(m)
        } else if at.join(format!("{m}.rs")).is_file() {
            at.join(format!("{m}.rs"))
        } else {
            return Some(format!("no module {m} in {}", rel(&at)));
        };
    }
    let item = item[0];
    if at.is_dir() && (at.join(item).is_dir() || at.join(format!("{item}.rs")).is_file()) {
        return None;
    }
    let mut sources = Vec::new();
    if at.is_dir() {
        rust_sources(&at, &mut sources);
    } else {
        sources.push(at.clone());
    }
    let declared = sources.iter().any(|f| {
        let text = read(f);
        [
            "fn", "struct", "enum", "trait", "type", "const", "static", "mod",
        ]
        .iter()
        .any(|kw| declares(&text, &format!("{kw} {item}")))
    });
    (!declared).then(|| format!("nothing named {item} in {}", rel(&at)))
}

/// Whether `text` holds `decl` (`fn name`) as whole words: after a line start or a space, before
/// a character that cannot continue the name.
fn declares(text: &str, decl: &str) -> bool {
    text.match_indices(decl).any(|(i, _)| {
        let before_ok = text[..i].ends_with([' ', '\n', '\t']) || i == 0;
        let after = text[i + decl.len()..].chars().next();
        before_ok && after.is_none_or(|c| !(c.is_alphanumeric() || c == '_'))
    })
}

/// Every `.rs` file under `dir`.
fn rust_sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for p in entries.filter_map(|e| e.ok().map(|e| e.path())) {
        if p.is_dir() {
            rust_sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every backticked repository path or `file.rs::test` of `files` that does not resolve.
fn broken_references(files: &[PathBuf]) -> Vec<String> {
    let mut out = Vec::new();
    for file in files {
        let text = read(file);
        for (n, line) in prose_lines(&text) {
            for span in code_spans(line) {
                if let Some(why) = broken_reference(span) {
                    out.push(format!("{}:{n}: {why}", rel(file)));
                }
            }
        }
    }
    out
}

#[test]
fn every_relative_link_and_anchor_in_the_docs_resolves() {
    let files = doc_files();
    // the reference pages the README sends a reader to
    for page in [
        "cli",
        "rest-api",
        "configuration",
        "data-formats",
        "deployment",
        "method",
        "hardware",
    ] {
        let path = root().join(format!("docs/{page}.md"));
        assert!(path.is_file(), "{} is missing", rel(&path));
    }
    let broken = broken_links(&files);
    assert!(
        broken.is_empty(),
        "broken links in the docs:\n{}",
        broken.join("\n")
    );
    // the checker itself: GitHub's anchors, and a broken link and anchor are found
    assert_eq!(
        slug("7. The paper experiment (paper §4, eq. 1–3)"),
        "7-the-paper-experiment-paper-4-eq-13"
    );
    assert_eq!(slug("`GET /api/campaigns/{id}`"), "get-apicampaignsid");
    assert_eq!(
        slug("The technician's questions"),
        "the-technicians-questions"
    );
    let text = "# A\n## B c\n## B c\n```\n# not a heading\n```\n";
    assert_eq!(
        anchors(text),
        ["a", "b-c", "b-c-1"].map(str::to_owned).into()
    );
    assert_eq!(
        link_targets("see [x](a.md#b), `[y](not/a/link)` and ![z](img.png)"),
        ["a.md#b", "img.png"]
    );
    let readme = root().join("README.md");
    assert!(broken_link(&readme, "docs/method.md").is_none());
    assert!(broken_link(&readme, "https://example.org/x").is_none());
    assert!(broken_link(&readme, "docs/no-such-page.md").is_some());
    assert!(broken_link(&readme, "docs/method.md#no-such-section").is_some());
    assert!(broken_link(&readme, "#no-such-section").is_some());
}

#[test]
fn every_repository_path_and_cited_test_in_the_docs_exists() {
    let broken = broken_references(&doc_files());
    assert!(
        broken.is_empty(),
        "the docs name paths or tests that do not exist:\n{}",
        broken.join("\n")
    );
    // the checker itself
    for ok in [
        "src/campaign/engine/{setup,frame}.rs",
        "tests/it/browser*.rs",
        "deploy/README.md §2a",
        "tests/it/docs.rs::every_repository_path_and_cited_test_in_the_docs_exists",
        "docs.rs::every_repository_path_and_cited_test_in_the_docs_exists",
        "target/screenshots/x.png",
        "cellcal run",
        "calibrate::quality::assess",
        "campaign::session::open_session",
        "model::tx60",
        "emscon::server::serve",
        "std::fs::read",
    ] {
        assert_eq!(broken_reference(ok), None, "{ok}");
    }
    for bad in [
        "src/report/quality.rs",
        "src/campaign/engine/{setup,nothing}.rs",
        "tests/it/docs.rs::no_such_test",
        "nowhere.rs::no_such_test",
        "report::calibrate",
        "report::quality::assess",
    ] {
        assert!(broken_reference(bad).is_some(), "{bad}");
    }
}

/// The output of `cellcal ARGS`.
fn help(args: &[&str]) -> String {
    let out = cellcal_process().args(args).output().expect("run cellcal");
    assert!(out.status.success(), "cellcal {args:?} --help failed");
    String::from_utf8(out.stdout).expect("UTF-8 help")
}

/// The subcommands `cellcal --help` lists (without `help`).
fn subcommands(top_help: &str) -> Vec<String> {
    top_help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_owned)
        .collect()
}

/// The long flags of one `--help` text (without `--help` and `--version`).
fn help_flags(sub_help: &str) -> BTreeSet<String> {
    sub_help
        .lines()
        .map(str::trim_start)
        .filter(|l| l.starts_with('-'))
        .filter_map(|l| l.split_whitespace().find(|w| w.starts_with("--")))
        .map(|w| {
            w.trim_start_matches('-')
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect::<String>()
        })
        .filter(|f| f != "help" && f != "version")
        .collect()
}

/// docs/cli.md's sections `` ## `cellcal SUB` `` and the flags each lists as `` - `--flag`… ``.
fn documented_flags(cli_md: &str) -> BTreeMap<String, BTreeSet<String>> {
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut current: Option<String> = None;
    for (_, line) in prose_lines(cli_md) {
        if let Some(h) = line.strip_prefix("## ") {
            current = h
                .trim()
                .strip_prefix("`cellcal ")
                .and_then(|s| s.strip_suffix('`'))
                .map(str::to_owned);
            if let Some(c) = &current {
                out.entry(c.clone()).or_default();
            }
            continue;
        }
        let (Some(sub), Some(item)) = (&current, line.strip_prefix("- `--")) else {
            continue;
        };
        let flag: String = item
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
            .collect();
        out.entry(sub.clone()).or_default().insert(flag);
    }
    out
}

#[test]
fn docs_cli_md_lists_exactly_the_flags_of_every_subcommand() {
    let path = root().join("docs/cli.md");
    let cli_md = std::fs::read_to_string(&path).unwrap_or_default();
    let documented = documented_flags(&cli_md);
    let subs = subcommands(&help(&["--help"]));
    assert!(subs.len() >= 10, "subcommands of cellcal --help: {subs:?}");
    let mut wrong = Vec::new();
    for sub in &subs {
        let shown = help_flags(&help(&[sub, "--help"]));
        let Some(listed) = documented.get(sub) else {
            wrong.push(format!("no section ## `cellcal {sub}` in docs/cli.md"));
            continue;
        };
        for f in shown.difference(listed) {
            wrong.push(format!(
                "cellcal {sub} --{f}: shown by --help, not listed in docs/cli.md (as - `--{f} …`)"
            ));
        }
        for f in listed.difference(&shown) {
            wrong.push(format!(
                "cellcal {sub} --{f}: listed in docs/cli.md, no such flag"
            ));
        }
    }
    for sub in documented.keys().filter(|s| !subs.contains(s)) {
        wrong.push(format!(
            "docs/cli.md documents `cellcal {sub}`, no such command"
        ));
    }
    assert!(wrong.is_empty(), "docs/cli.md:\n{}", wrong.join("\n"));
    // the parsers themselves
    let sample =
        "Options:\n      --config <CONFIG>  File [default: x]\n  -h, --help  Print\n      \
                  --robust [<ROBUST>]\n          Down-weight, see --store\n      --arm  Go\n";
    assert_eq!(
        help_flags(sample),
        ["arm", "config", "robust"].map(str::to_owned).into()
    );
    let md = "## `cellcal run`\n- `--arm`: go\n- `--config CELL.toml`: file\ntext `--not-a-flag`\n\
              ## Exit codes\n- `--x`\n";
    assert_eq!(
        documented_flags(md),
        BTreeMap::from([(
            "run".to_owned(),
            ["arm", "config"].map(str::to_owned).into()
        )])
    );
}

/// `METHOD /path` of every operation in the OpenAPI document.
fn openapi_routes() -> BTreeSet<String> {
    let doc: serde_json::Value =
        serde_json::from_str(&read(&root().join("tests/snapshots/openapi.json"))).expect("JSON");
    let mut out = BTreeSet::new();
    for (path, ops) in doc["paths"].as_object().expect("paths") {
        for method in ops.as_object().expect("operations").keys() {
            if ["get", "post", "put", "patch", "delete", "head"].contains(&method.as_str()) {
                out.insert(format!("{} {path}", method.to_uppercase()));
            }
        }
    }
    out
}

/// The routes docs/rest-api.md documents, one heading `` ### `METHOD /path` `` each.
fn documented_routes(rest_md: &str) -> BTreeSet<String> {
    prose_lines(rest_md)
        .into_iter()
        .filter_map(|(_, l)| l.strip_prefix("### `")?.strip_suffix('`'))
        .filter(|r| {
            r.split_once(' ').is_some_and(|(m, p)| {
                m.chars().all(|c| c.is_ascii_uppercase()) && p.starts_with('/')
            })
        })
        .map(str::to_owned)
        .collect()
}

#[test]
fn docs_rest_api_md_documents_exactly_the_routes_of_the_openapi_document() {
    let rest_md = std::fs::read_to_string(root().join("docs/rest-api.md")).unwrap_or_default();
    let documented = documented_routes(&rest_md);
    let served = openapi_routes();
    assert!(served.len() >= 15, "routes: {served:?}");
    let missing: Vec<_> = served.difference(&documented).collect();
    let extra: Vec<_> = documented.difference(&served).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "docs/rest-api.md (one heading ### `METHOD /path` per route):\n\
         not documented: {missing:?}\nnot in tests/snapshots/openapi.json: {extra:?}"
    );
    assert_eq!(
        documented_routes("### `GET /api/health`\n### `GET` the rest\n```\n### `POST /x`\n```\n"),
        ["GET /api/health".to_owned()].into()
    );
}

/// Every key the TOML text sets, or shows commented out (`# key = …`), with its table names.
fn toml_keys(text: &str) -> BTreeSet<String> {
    fn walk(table: &toml::Table, out: &mut BTreeSet<String>) {
        for (k, v) in table {
            out.insert(k.clone());
            if let toml::Value::Table(t) = v {
                walk(t, out);
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(&toml::from_str(text).expect("TOML"), &mut out);
    for line in text.lines() {
        let Some(rest) = line.trim_start().strip_prefix('#') else {
            continue;
        };
        let Some((key, _)) = rest.trim_start().split_once(" = ") else {
            continue;
        };
        if !key.is_empty() && key.chars().all(|c| c.is_ascii_lowercase() || c == '_') {
            out.insert(key.to_owned());
        }
    }
    out
}

#[test]
fn docs_configuration_md_names_every_key_of_the_shipped_configuration_files() {
    let doc = std::fs::read_to_string(root().join("docs/configuration.md")).unwrap_or_default();
    let words: BTreeSet<&str> = prose_lines(&doc)
        .into_iter()
        .flat_map(|(_, l)| code_spans(l))
        .chain(doc.split("```").skip(1).step_by(2))
        .flat_map(|s| s.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_')))
        .collect();
    let mut missing = Vec::new();
    for file in ["config/cell.example.toml", "config/cell.sim.toml"] {
        for key in toml_keys(&read(&root().join(file))) {
            if !words.contains(key.as_str()) {
                missing.push(format!("{file}: `{key}`"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "keys not documented in docs/configuration.md:\n{}",
        missing.join("\n")
    );
}

#[test]
fn the_readme_fits_a_start_and_points_at_the_reference() {
    let readme = read(&root().join("README.md"));
    let lines = readme.lines().count();
    assert!(
        lines <= 160,
        "README.md has {lines} lines, over 160: move reference text into docs/"
    );
    // the two commands, exactly: .ci/run runs the second verbatim
    let ci = read(&root().join(".ci/run"));
    let test_command = ci
        .lines()
        .rev()
        .find(|l| l.starts_with("cargo test"))
        .expect(".ci/run runs the tests");
    for command in [
        "cargo run --release -- run --config config/cell.sim.toml --arm --store campaign.db --json result.json",
        test_command,
    ] {
        assert!(readme.contains(command), "README.md shows `{command}`");
    }
    for page in [
        "cli",
        "rest-api",
        "configuration",
        "data-formats",
        "deployment",
        "method",
    ] {
        assert!(
            readme.contains(&format!("](docs/{page}.md")),
            "README.md links docs/{page}.md"
        );
    }
}
