//! The top-level modules of `src/` import one way: each sits on a layer and names only
//! modules on lower layers (docs/architecture.md draws the layers and says why each
//! module sits where it does). A file in `src/<a>/` or `src/<a>.rs` imports `b` when it
//! names `crate::b` (also inside `use crate::{b, ...}`) or reaches `b` through
//! `super::super::b` from below `a`. Unit tests (`#[cfg(test)] mod tests` and what
//! follows it in the file) may reach any layer. Modules on one layer must not import
//! each other, so no cycle can hide inside a layer.
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// Every top-level module with its layer: a module may import only modules on a lower
/// layer.
const LAYERS: &[(&str, u32)] = &[
    // Leaves: the physics, and the validation toolkit every section is checked with.
    ("model", 0),
    ("checks", 0),
    // The tracker and its options; the device traits and their samples.
    ("vision", 1),
    ("hw", 1),
    // The renderer (draws the probe the model bends, binarised as vision does); the
    // teleoperation law (reads hw's samples and the tracker's estimate).
    ("scene", 2),
    ("control", 2),
    // The simulated lab and its "sim" devices; recorded sessions on disk.
    ("sim", 3),
    ("session", 3),
    // TOML -> validated Config, over every section's owner.
    ("config", 4),
    // `nanoforce report`, from a session and its configuration.
    ("report", 5),
    // The real-time daemon with its stream and monitor threads, opening the lab.
    ("daemon", 6),
    // The command line over everything.
    ("cli", 7),
];

/// One import of another top-level module.
#[derive(Debug, Clone, PartialEq)]
struct Import {
    line: usize,
    target: String,
}

/// The top-level module a file belongs to and the file's module path below `src/`
/// (`src/daemon/stream/mod.rs` -> `["daemon", "stream"]`), or None for the crate root.
fn module_path(src: &Path, file: &Path) -> Option<Vec<String>> {
    let relative = file.strip_prefix(src).ok()?;
    let mut parts: Vec<String> = relative
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop()?;
    let stem = last.strip_suffix(".rs")?;
    if parts.is_empty() && (stem == "lib" || stem == "main") {
        return None;
    }
    if stem != "mod" {
        parts.push(stem.to_string());
    }
    Some(parts)
}

/// The file's text without its unit tests.
fn without_unit_tests(text: &str) -> &str {
    let mut from = 0;
    while let Some(at) = text[from..].find("#[cfg(test)]") {
        let start = from + at;
        let rest = text[start + "#[cfg(test)]".len()..].trim_start();
        if rest.starts_with("mod tests") {
            return &text[..start];
        }
        from = start + 1;
    }
    text
}

fn is_ident_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The identifier at the start of `text`.
fn ident(text: &str) -> &str {
    let end = text.find(|c| !is_ident_char(c)).unwrap_or(text.len());
    &text[..end]
}

/// The names at the top level of a `{a, b::c, d::{e, f}}` group (`text` starts after
/// the opening brace): `["a", "b", "d"]`.
fn group_heads(text: &str) -> Vec<&str> {
    let mut heads = Vec::new();
    let mut depth = 0;
    let mut expect_head = true;
    for (i, c) in text.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => expect_head = true,
            c if expect_head && depth == 0 && is_ident_char(c) => {
                heads.push(ident(&text[i..]));
                expect_head = false;
            }
            _ => {}
        }
    }
    heads
}

/// Every other top-level module a file of module `path` names, with its line.
fn imports(path: &[String], text: &str) -> Vec<Import> {
    let text = without_unit_tests(text);
    let line_of = |at: usize| text[..at].matches('\n').count() + 1;
    let mut found = Vec::new();
    let mut push = |at: usize, target: &str| {
        if !target.is_empty() && target != path[0] && target != "self" {
            found.push(Import {
                line: line_of(at),
                target: target.to_string(),
            });
        }
    };
    for (at, _) in text.match_indices("crate::") {
        let before = text[..at].chars().next_back();
        if before.is_some_and(is_ident_char) {
            continue;
        }
        let rest = &text[at + "crate::".len()..];
        match rest.strip_prefix('{') {
            Some(group) => group_heads(group).into_iter().for_each(|t| push(at, t)),
            None => push(at, ident(rest)),
        }
    }
    for (at, _) in text.match_indices("super::") {
        let before = text[..at].chars().next_back();
        if before.is_some_and(|c| is_ident_char(c) || c == ':') {
            continue;
        }
        // `super::` repeated k times from module `path` reaches `path[..len - k]`; at the
        // crate root the next name is a top-level module.
        let mut rest = &text[at..];
        let mut ups = 0;
        while let Some(r) = rest.strip_prefix("super::") {
            rest = r;
            ups += 1;
        }
        if ups == path.len() {
            match rest.strip_prefix('{') {
                Some(group) => group_heads(group).into_iter().for_each(|t| push(at, t)),
                None => push(at, ident(rest)),
            }
        }
    }
    found
}

fn rust_files(dir: &Path, files: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            entry
                .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
                .path()
        })
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            rust_files(&path, files);
        } else if path.extension().is_some_and(|e| e == "rs") {
            files.push(path);
        }
    }
}

/// Every import of `src`, by file: (file, its top-level module, imports).
fn scan(src: &Path) -> Vec<(PathBuf, String, Vec<Import>)> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files
        .into_iter()
        .filter_map(|file| {
            let path = module_path(src, &file)?;
            let text =
                fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            let found = imports(&path, &text);
            Some((file, path[0].clone(), found))
        })
        .collect()
}

#[test]
fn imports_go_down_the_layers() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let layer: BTreeMap<&str, u32> = LAYERS.iter().copied().collect();
    let mut wrong = Vec::new();
    let mut edges = 0;
    for (file, module, found) in scan(&root.join("src")) {
        let file = file.strip_prefix(root).unwrap_or(&file);
        let Some(&from) = layer.get(module.as_str()) else {
            wrong.push(format!(
                "{}: module `{module}` has no layer in tests/layering.rs",
                file.display()
            ));
            continue;
        };
        for import in found {
            edges += 1;
            match layer.get(import.target.as_str()) {
                Some(&to) if to < from => {}
                Some(&to) => wrong.push(format!(
                    "{}:{}: `{module}` (layer {from}) imports `{}` (layer {to}); \
                     a module may import only lower layers",
                    file.display(),
                    import.line,
                    import.target
                )),
                // `crate::` followed by a name that is not a module (a macro's `$crate`).
                None => {}
            }
        }
    }
    assert!(wrong.is_empty(), "upward imports:\n{}", wrong.join("\n"));
    // The scan sees the imports that are there (daemon alone names a dozen).
    assert!(
        edges > 100,
        "only {edges} imports found: the scan is broken"
    );
}

#[test]
fn every_module_of_src_has_a_layer() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut modules: Vec<String> = fs::read_dir(&src)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter_map(|p| {
            let name = p.file_name()?.to_str()?.to_string();
            match name.strip_suffix(".rs") {
                Some("lib" | "main") => None,
                Some(stem) => Some(stem.to_string()),
                None if p.is_dir() => Some(name),
                None => None,
            }
        })
        .collect();
    modules.sort();
    let mut declared: Vec<String> = LAYERS.iter().map(|(m, _)| m.to_string()).collect();
    declared.sort();
    assert_eq!(modules, declared, "src/ modules vs the layer table");
}

#[test]
fn the_scan_finds_every_spelling_of_an_import() {
    let path = |p: &str| p.split('/').map(String::from).collect::<Vec<_>>();
    let targets = |p: &str, text: &str| {
        imports(&path(p), text)
            .into_iter()
            .map(|i| (i.line, i.target))
            .collect::<Vec<_>>()
    };
    assert_eq!(
        targets("vision/tracker", "use crate::config::Threshold;\n"),
        [(1, "config".to_string())]
    );
    assert_eq!(
        targets(
            "scene",
            "//! doc\nuse crate::{\n    config::{A, B},\n    model,\n    vision::X,\n};\n"
        ),
        [
            (2, "config".into()),
            (2, "model".into()),
            (2, "vision".into())
        ]
    );
    // From daemon/stream/datagram.rs `super::super` is daemon; one more is the root.
    assert_eq!(
        targets("daemon/stream/datagram", "use super::super::Estimator;\n"),
        []
    );
    assert_eq!(
        targets(
            "hw/open",
            "let x = super::super::daemon::rt::sleep_until(0, 0);\n"
        ),
        [(1, "daemon".into())]
    );
    // Its own module, `$crate` in a macro of its own, and names that only end in crate.
    assert_eq!(
        targets(
            "vision/simd",
            "$crate::vision::simd::avx2();\nmy_crate::hw::x();\npub(crate) fn f() {}\n"
        ),
        []
    );
    // Unit tests may reach any layer.
    assert_eq!(
        targets(
            "hw/config",
            "use crate::checks::Checker;\n#[cfg(test)]\nmod tests {\n    use crate::config::Config;\n}\n"
        ),
        [(1, "checks".into())]
    );
}
