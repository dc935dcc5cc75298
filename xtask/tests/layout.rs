//! `docs/layout.md` against the tree: every source file of every crate is named in its crate's
//! entry of "Inside the crates", and every file an entry names exists, so that the map cannot
//! drift from the modules.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// `.rs` files under `dir`, as paths relative to it.
fn sources(dir: &Path, under: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, under, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path.strip_prefix(under).unwrap().to_path_buf());
        }
    }
}

/// Each "- `CRATE/src`: ..." entry's crate and text, up to the next entry or heading.
fn entries(layout: &str) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    for line in layout.lines() {
        if let Some(rest) = line.strip_prefix("- `")
            && let Some((krate, text)) = rest.split_once("/src`")
        {
            out.push((krate.to_string(), text.to_string()));
        } else if line.starts_with('#') || line.starts_with("- ") || line.is_empty() {
            // The entry's text ends at a blank line, a heading or another list item.
            if let Some(last) = out.last_mut()
                && !last.1.ends_with('\u{0}')
            {
                last.1.push('\u{0}');
            }
        } else if let Some(last) = out.last_mut()
            && !last.1.ends_with('\u{0}')
        {
            last.1.push(' ');
            last.1.push_str(line.trim());
        }
    }
    out
}

#[test]
fn the_layout_names_every_module_and_only_modules_that_exist() {
    let root = root();
    let layout = std::fs::read_to_string(root.join("docs/layout.md")).unwrap();
    let entries = entries(&layout);
    let members = ["sensor", "formats", "dataset", "gelcam", "model", "train", "infer", "xtask", "python"];
    let mut missing = Vec::new();
    let mut phantom = Vec::new();
    for krate in members {
        let Some((_, text)) = entries.iter().find(|(k, _)| k == krate) else {
            missing.push(format!("{krate}: no `{krate}/src` entry"));
            continue;
        };
        let src = root.join(krate).join("src");
        let mut files = Vec::new();
        sources(&src, &src, &mut files);
        for file in &files {
            let name = file.file_name().unwrap().to_str().unwrap();
            let named = match name {
                "lib.rs" | "main.rs" if file.parent() == Some(Path::new("")) => true,
                "mod.rs" => {
                    let dir = file.parent().unwrap().file_name().unwrap().to_str().unwrap();
                    text.contains(&format!("{dir}/"))
                }
                _ => text.contains(&format!("`{name}`")) || text.contains(&format!("{name}`")),
            };
            if !named {
                missing.push(format!("{krate}/src/{}", file.display()));
            }
        }
        // Every `NAME.rs` the entry names is a file of the crate.
        for token in text.split('`').skip(1).step_by(2) {
            if let Some(stem) = token.strip_suffix(".rs") {
                let wanted = format!("{}.rs", stem.rsplit('/').next().unwrap());
                // A path with a folder may also be the crate's own (`tests/common/kill.rs`).
                let beside = token.contains('/') && root.join(krate).join(token).is_file();
                if !beside && !files.iter().any(|f| f.ends_with(&wanted)) {
                    phantom.push(format!("{krate}: `{token}`"));
                }
            }
        }
    }
    assert!(missing.is_empty(), "docs/layout.md does not name these sources: {missing:#?}");
    assert!(phantom.is_empty(), "docs/layout.md names files that do not exist: {phantom:#?}");
}

/// Each source file's module path in its crate (`kernels::conv`; the root is ``) and its text
/// without comment lines and without its test module.
fn modules(src: &Path) -> Vec<(String, String)> {
    let mut files = Vec::new();
    sources(src, src, &mut files);
    files
        .into_iter()
        .map(|f| {
            let path = f.with_extension("").to_string_lossy().replace('/', "::");
            let path = path.strip_suffix("::mod").unwrap_or(&path).to_string();
            let path = if path == "lib" || path == "main" { String::new() } else { path };
            let text = std::fs::read_to_string(src.join(&f)).unwrap();
            let code = text.split("#[cfg(test)]\nmod tests").next().unwrap();
            let code = code.split("#[cfg(all(test").next().unwrap();
            let code: Vec<&str> = code.lines().filter(|l| !l.trim_start().starts_with("//")).collect();
            (path, code.join("\n"))
        })
        .collect()
}

/// Whether `text` names `path` as a whole path segment sequence after `prefix`.
fn names(text: &str, prefix: &str, path: &str) -> bool {
    let needle = format!("{prefix}{path}");
    text.match_indices(&needle).any(|(i, _)| {
        let next = text[i + needle.len()..].chars().next();
        !next.is_some_and(|c| c.is_alphanumeric() || c == '_')
    })
}

/// No two files of a crate import each other, directly or around a circle (references to a
/// module's own ancestors, where Rust declares it, do not count): the kernels are a tree.
#[test]
fn no_file_imports_another_that_imports_it_back() {
    let root = root();
    let mut circles = Vec::new();
    for krate in ["sensor", "formats", "dataset", "gelcam", "model", "train", "infer", "xtask"] {
        let mods = modules(&root.join(krate).join("src"));
        let named: Vec<&str> = mods.iter().map(|(m, _)| m.as_str()).filter(|m| !m.is_empty()).collect();
        let edges: Vec<Vec<usize>> = mods
            .iter()
            .map(|(m, text)| {
                let parent = m.rsplit_once("::").map_or("", |(p, _)| p);
                named
                    .iter()
                    .filter(|other| **other != m && !m.starts_with(&format!("{other}::")))
                    .filter(|other| {
                        names(text, "crate::", other)
                            || other.rsplit_once("::").map_or(parent.is_empty(), |(p, _)| p == parent)
                                && names(text, "super::", other.rsplit("::").next().unwrap())
                    })
                    .map(|other| mods.iter().position(|(n, _)| n == other).unwrap())
                    .collect()
            })
            .collect();
        // Depth-first: a module met again while still on the path closes a circle.
        fn visit(n: usize, edges: &[Vec<usize>], state: &mut [u8], path: &mut Vec<usize>, found: &mut Vec<Vec<usize>>) {
            state[n] = 1;
            path.push(n);
            for &k in &edges[n] {
                match state[k] {
                    0 => visit(k, edges, state, path, found),
                    1 => found.push(path[path.iter().position(|&p| p == k).unwrap()..].to_vec()),
                    _ => {}
                }
            }
            path.pop();
            state[n] = 2;
        }
        let mut state = vec![0u8; mods.len()];
        let mut found = Vec::new();
        for n in 0..mods.len() {
            if state[n] == 0 {
                visit(n, &edges, &mut state, &mut Vec::new(), &mut found);
            }
        }
        for circle in found {
            let names: Vec<&str> = circle.iter().map(|&k| mods[k].0.as_str()).collect();
            circles.push(format!("{krate}: {}", names.join(" -> ")));
        }
    }
    assert!(circles.is_empty(), "files that import each other: {circles:#?}");
}
