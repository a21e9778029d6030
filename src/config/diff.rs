//! Which keys differ between two TOML documents (a stored campaign's configuration and the
//! one a resume is given).

/// The dotted keys whose values differ between `old` and `new` (added, removed or changed),
/// sorted; top-level tables named in `ignore` are skipped. A document that does not parse is
/// reported as the key `(whole file)`.
pub fn changed_keys(old: &str, new: &str, ignore: &[&str]) -> Vec<String> {
    let (Ok(a), Ok(b)) = (old.parse::<toml::Table>(), new.parse::<toml::Table>()) else {
        return if old == new {
            Vec::new()
        } else {
            vec!["(whole file)".to_owned()]
        };
    };
    let mut out = Vec::new();
    diff_tables(&a, &b, "", ignore, &mut out);
    out.sort();
    out
}

fn diff_tables(
    a: &toml::Table,
    b: &toml::Table,
    prefix: &str,
    ignore: &[&str],
    out: &mut Vec<String>,
) {
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    for k in keys {
        if prefix.is_empty() && ignore.contains(&k.as_str()) {
            continue;
        }
        let name = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match (a.get(k), b.get(k)) {
            (Some(toml::Value::Table(x)), Some(toml::Value::Table(y))) => {
                diff_tables(x, y, &name, &[], out)
            }
            (x, y) if x != y => out.push(name),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::changed_keys;

    #[test]
    fn names_changed_added_and_removed_keys_and_skips_ignored_tables() {
        let old = "a = 1\n[t]\nx = [1.0, 2.0]\ny = \"s\"\n[sim]\nseed = 1\n";
        let new = "a = 1\nb = 2\n[t]\nx = [1.0, 2.5]\n[sim]\nseed = 2\n";
        assert_eq!(changed_keys(old, new, &["sim"]), ["b", "t.x", "t.y"]);
        assert!(changed_keys(old, old, &[]).is_empty());
        // comments and formatting are not changes
        assert!(changed_keys("a = 1 # c\n", "a=1\n", &[]).is_empty());
        assert_eq!(changed_keys("a = [", "a = 1", &[]), ["(whole file)"]);
    }
}
