//! No import cycles between the modules of a crate (ARCHITECTURE.md, rule 1).
//!
//! The module graph is read from the sources as text: every module (a file
//! under `crates/<name>/src`, `mod.rs`/`lib.rs`/`main.rs` standing for their
//! folder) gets an edge to each module its non-test code names through a
//! `crate::…` path (use trees with `{…}` groups expanded) or a `super::…`
//! path. A path resolves to the longest module prefix it names. Edges from a
//! module to its own ancestors are left out: a child using its parent's
//! items is how Rust modules nest, not a layering problem. Any strongly
//! connected component of more than one module is a cycle and fails the test
//! with the modules and the edges that close it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Module path inside a crate (`["calibration", "step"]`; the crate root is `[]`).
type ModPath = Vec<String>;
type Graph = BTreeMap<ModPath, BTreeSet<ModPath>>;

/// Every `.rs` file under `src`, keyed by its module path.
fn modules(src: &Path) -> BTreeMap<ModPath, PathBuf> {
    let mut out = BTreeMap::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("read a source folder") {
            let path = entry.expect("read a folder entry").path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let rel = path.strip_prefix(src).expect("path under src");
                let mut parts: ModPath = rel
                    .with_extension("")
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                if matches!(
                    parts.last().map(String::as_str),
                    Some("mod" | "lib" | "main")
                ) {
                    parts.pop();
                }
                out.insert(parts, path);
            }
        }
    }
    out
}

/// The code a module contributes to the graph: everything before its first
/// `#[cfg(test)]`, without line comments.
fn code_of(text: &str) -> String {
    let text = match text.find("#[cfg(test)]") {
        Some(i) => &text[..i],
        None => text,
    };
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Expand a use tree starting at `s` (just after `crate::` or `super::`)
/// into full paths, e.g. `a::{b, c::d}` → `a::b`, `a::c::d`.
fn expand(s: &str) -> Vec<ModPath> {
    fn tree(s: &[u8], i: &mut usize, prefix: &ModPath, out: &mut Vec<ModPath>) {
        let mut path = prefix.clone();
        loop {
            while *i < s.len() && s[*i].is_ascii_whitespace() {
                *i += 1;
            }
            if *i < s.len() && s[*i] == b'{' {
                *i += 1;
                loop {
                    tree(s, i, &path, out);
                    while *i < s.len() && s[*i].is_ascii_whitespace() {
                        *i += 1;
                    }
                    match s.get(*i) {
                        Some(b',') => *i += 1,
                        Some(b'}') => {
                            *i += 1;
                            return;
                        }
                        _ => return,
                    }
                    while *i < s.len() && s[*i].is_ascii_whitespace() {
                        *i += 1;
                    }
                    if s.get(*i) == Some(&b'}') {
                        *i += 1;
                        return;
                    }
                }
            }
            let start = *i;
            while *i < s.len() && (s[*i].is_ascii_alphanumeric() || s[*i] == b'_') {
                *i += 1;
            }
            if *i == start {
                out.push(path);
                return;
            }
            let seg = String::from_utf8_lossy(&s[start..*i]).into_owned();
            if seg != "self" {
                path.push(seg);
            }
            if s[*i..].starts_with(b"::") {
                *i += 2;
            } else {
                out.push(path);
                return;
            }
        }
    }
    let mut out = Vec::new();
    let mut i = 0;
    tree(s.as_bytes(), &mut i, &Vec::new(), &mut out);
    out
}

/// The longest prefix of `path` that is a module.
fn resolve(mods: &BTreeMap<ModPath, PathBuf>, path: &[String]) -> Option<ModPath> {
    (1..=path.len())
        .rev()
        .map(|k| path[..k].to_vec())
        .find(|p| mods.contains_key(p))
}

/// The module graph of the crate whose sources are in `src`.
fn graph(src: &Path) -> Graph {
    let mods = modules(src);
    let mut g = Graph::new();
    for (m, file) in &mods {
        let text = std::fs::read_to_string(file).expect("read a source file");
        let code = code_of(&text);
        let mut targets = BTreeSet::new();
        for (at, _) in code.match_indices("crate::") {
            for p in expand(&code[at + "crate::".len()..]) {
                targets.extend(resolve(&mods, &p));
            }
        }
        for (at, _) in code.match_indices("super::") {
            // `super::super::x` counts once, at its first `super`.
            if code[..at].ends_with("super::") {
                continue;
            }
            let mut rest = &code[at..];
            let mut base = m.clone();
            while let Some(r) = rest.strip_prefix("super::") {
                base.pop();
                rest = r;
            }
            for p in expand(rest) {
                let full: ModPath = base.iter().cloned().chain(p).collect();
                targets.extend(resolve(&mods, &full));
            }
        }
        targets.retain(|t| t != m && !(m.len() > t.len() && m[..t.len()] == t[..]));
        g.insert(m.clone(), targets);
    }
    g
}

/// Strongly connected components with more than one module (Tarjan).
fn cycles(g: &Graph) -> Vec<Vec<ModPath>> {
    struct Tarjan<'a> {
        g: &'a Graph,
        index: BTreeMap<&'a ModPath, usize>,
        low: BTreeMap<&'a ModPath, usize>,
        stack: Vec<&'a ModPath>,
        on: BTreeSet<&'a ModPath>,
        out: Vec<Vec<ModPath>>,
    }
    impl<'a> Tarjan<'a> {
        fn visit(&mut self, v: &'a ModPath) {
            let n = self.index.len();
            self.index.insert(v, n);
            self.low.insert(v, n);
            self.stack.push(v);
            self.on.insert(v);
            let g = self.g;
            for w in g.get(v).into_iter().flatten() {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(lw);
                } else if self.on.contains(w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut comp = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on.remove(w);
                    comp.push(w.clone());
                    if w == v {
                        break;
                    }
                }
                if comp.len() > 1 {
                    comp.sort();
                    self.out.push(comp);
                }
            }
        }
    }
    let mut t = Tarjan {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in g.keys() {
        if !t.index.contains_key(v) {
            t.visit(v);
        }
    }
    t.out
}

fn name(m: &ModPath) -> String {
    if m.is_empty() {
        "(crate root)".into()
    } else {
        m.join("::")
    }
}

#[test]
fn no_import_cycle_inside_any_crate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut report = String::new();
    let mut n_modules = 0;
    for krate in ["proto", "dsp", "rig", "study", "app"] {
        let src = root.join("crates").join(krate).join("src");
        let g = graph(&src);
        n_modules += g.len();
        for comp in cycles(&g) {
            report += &format!("crate {krate}: cycle between {}\n", {
                comp.iter().map(name).collect::<Vec<_>>().join(", ")
            });
            for m in &comp {
                for t in g[m].iter().filter(|t| comp.contains(t)) {
                    report += &format!("    {} → {}\n", name(m), name(t));
                }
            }
        }
    }
    // The reader must have seen the crates (a moved folder would pass vacuously).
    assert!(n_modules > 100, "only {n_modules} modules found");
    assert!(report.is_empty(), "import cycles:\n{report}");
}

/// The reader and the cycle finder on a small tree written here: `a` and
/// `b` name each other (one through a `{…}` group, one through `super`),
/// `c` only uses its parent (not an edge), `d` uses `a` (no cycle).
#[test]
fn the_check_finds_a_planted_cycle() {
    let dir = std::env::temp_dir().join(format!("kilotouch-module-graph-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("p")).expect("temp folder");
    let files = [
        ("lib.rs", "mod p; mod d;\n"),
        ("p/mod.rs", "pub mod a; pub mod b; pub mod c;\n"),
        (
            "p/a.rs",
            "use crate::p::{b::Thing, c};\n// crate::d in a comment is no edge\n",
        ),
        ("p/b.rs", "pub struct Thing;\nfn f() { super::a::g() }\n"),
        ("p/c.rs", "use crate::p::Shared;\n"),
        (
            "d.rs",
            "use crate::p::a;\n#[cfg(test)]\nmod tests { use crate::p::b; }\n",
        ),
    ];
    for (f, text) in files {
        std::fs::write(dir.join(f), text).expect("write a file");
    }
    let g = graph(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    let m = |s: &str| -> ModPath { s.split("::").map(String::from).collect() };
    assert_eq!(g[&m("p::a")], [m("p::b"), m("p::c")].into());
    assert_eq!(g[&m("p::b")], [m("p::a")].into());
    assert!(g[&m("p::c")].is_empty(), "{:?}", g[&m("p::c")]);
    assert_eq!(g[&m("d")], [m("p::a")].into());
    assert_eq!(cycles(&g), vec![vec![m("p::a"), m("p::b")]]);
}
