//! Where a field is in a TOML text: the line and column of a byte offset,
//! the offset of a dotted field path (`task.circling.timeout_s`,
//! `conditions[1]`, `tweezer.obstacles[0].radius_m`) and the path of the
//! field at an offset. Every file format of the workspace (rig files,
//! protocols) uses it to name the line and the field of an error; it reads
//! toml's spans, so it follows the text however it is written.

use toml::Spanned;
use toml::de::{DeTable, DeValue};

/// 1-based line and column (in characters) of byte `offset` of `src`;
/// `None` when `offset` is not on a character boundary.
pub fn line_col(src: &str, offset: usize) -> (Option<usize>, Option<usize>) {
    let offset = offset.min(src.len());
    let Some(before) = src.get(..offset) else {
        return (None, None);
    };
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (Some(line), Some(col))
}

/// A deserialisation message of toml/serde in a researcher's words:
/// Rust type names become what they mean (`f64` → "a number", `u32` → "a
/// whole number ≥ 0"), `invalid type: string "x"` → `got the text "x"`,
/// `unknown field` → `unknown key`, `missing field` → `the key … is
/// missing`. Anything else is kept as it is.
pub fn researcher_words(message: &str) -> String {
    let mut m = message.trim().to_owned();
    for (from, to) in [
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
        ("expected u8", "expected a whole number ≥ 0"),
        ("expected u16", "expected a whole number ≥ 0"),
        ("expected u32", "expected a whole number ≥ 0"),
        ("expected u64", "expected a whole number ≥ 0"),
        ("expected usize", "expected a whole number ≥ 0"),
        ("expected i32", "expected a whole number"),
        ("expected i64", "expected a whole number"),
        ("expected a boolean", "expected true or false"),
        ("expected a string", "expected a text in quotes"),
        (
            "expected a sequence",
            "expected a list in brackets, e.g. [1, 2]",
        ),
        ("invalid type: string ", "got the text "),
        ("invalid type: integer ", "got the whole number "),
        ("invalid type: floating point ", "got the number "),
        ("invalid type: boolean ", "got "),
        ("invalid type: sequence", "got a list"),
        ("invalid type: map", "got a table"),
        ("invalid value: integer ", "got "),
        ("unknown field ", "unknown key "),
        ("unknown variant ", "unknown value "),
        ("missing field ", "missing key "),
    ] {
        m = m.replace(from, to);
    }
    m.replace(", expected one of ", "; allowed here: ")
}

enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

/// `task.circling.timeout_s` → keys; `conditions[2]` → key + index.
fn parse_path(path: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in path.split('.') {
        match part.split_once('[') {
            Some((key, rest)) => {
                out.push(Seg::Key(key));
                if let Ok(i) = rest.trim_end_matches(']').parse() {
                    out.push(Seg::Index(i));
                }
            }
            None => out.push(Seg::Key(part)),
        }
    }
    out
}

/// Byte offset of the value at `path` in `src`, or of the deepest existing
/// ancestor (e.g. the table of a missing key); `None` if nothing matches.
pub fn locate(src: &str, path: &str) -> Option<usize> {
    let doc = DeTable::parse(src).ok()?;
    let mut best: Option<usize> = None;
    let mut table: Option<&DeTable<'_>> = Some(doc.get_ref());
    let mut value: Option<&Spanned<DeValue<'_>>> = None;
    for seg in parse_path(path) {
        let next = match (seg, table, value) {
            (Seg::Key(k), Some(t), _) => t.get(k),
            (Seg::Key(k), None, Some(v)) => v.get_ref().get(k),
            (Seg::Index(i), _, Some(v)) => v.get_ref().get(i),
            _ => None,
        };
        let Some(next) = next else { break };
        let span = next.span();
        // Implicit parent tables of `[a.b]` headers may carry an empty span.
        if span.end > span.start {
            best = Some(span.start);
        }
        table = None;
        value = Some(next);
    }
    best
}

/// Dotted path of the key or value containing byte `offset`.
pub fn field_at(src: &str, offset: usize) -> Option<String> {
    let doc = DeTable::parse(src).ok()?;
    let mut path = String::new();
    descend_table(doc.get_ref(), offset, &mut path);
    (!path.is_empty()).then_some(path)
}

fn descend_table(t: &DeTable<'_>, offset: usize, path: &mut String) {
    for (k, v) in t.iter() {
        let in_key = k.span().contains(&offset);
        let in_value = v.span().contains(&offset);
        if in_key || in_value {
            if !path.is_empty() {
                path.push('.');
            }
            path.push_str(k.get_ref());
            if in_value {
                descend_value(v, offset, path);
            }
            return;
        }
    }
    // Headers (`[task.circling]`) give tables whose span may not cover the
    // keys below them: search children by their own spans.
    for (k, v) in t.iter() {
        if let DeValue::Table(inner) = v.get_ref() {
            let mut sub = String::new();
            descend_table(inner, offset, &mut sub);
            if !sub.is_empty() {
                if !path.is_empty() {
                    path.push('.');
                }
                path.push_str(k.get_ref());
                path.push('.');
                path.push_str(&sub);
                return;
            }
        }
    }
}

fn descend_value(v: &Spanned<DeValue<'_>>, offset: usize, path: &mut String) {
    match v.get_ref() {
        DeValue::Table(t) => descend_table(t, offset, path),
        DeValue::Array(a) => {
            if let Some((i, item)) = a
                .iter()
                .enumerate()
                .find(|(_, item)| item.span().contains(&offset))
            {
                path.push_str(&format!("[{i}]"));
                descend_value(item, offset, path);
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_col_counts_characters() {
        let src = "a = 1\nµµ = 2\n";
        assert_eq!(line_col(src, 0), (Some(1), Some(1)));
        let off = src.find("= 2").unwrap();
        assert_eq!(line_col(src, off), (Some(2), Some(4)));
    }

    #[test]
    fn locate_and_field_at_agree() {
        let src = "name = \"x\"\nparticipants = 3\nconditions = [\"V\", \"D\"]\n\n[task.circling]\ntimeout_s = 5.0\n";
        let off = locate(src, "task.circling.timeout_s").unwrap();
        assert_eq!(line_col(src, off).0, Some(6));
        assert_eq!(
            field_at(src, off).as_deref(),
            Some("task.circling.timeout_s")
        );
        let off = locate(src, "conditions[1]").unwrap();
        assert_eq!(&src[off..off + 3], "\"D\"");
        assert_eq!(field_at(src, off).as_deref(), Some("conditions[1]"));
        // Missing key: falls back to its table.
        let off = locate(src, "task.circling.revolutions").unwrap();
        assert_eq!(line_col(src, off).0, Some(5));
        assert_eq!(locate(src, "nope"), None);
    }
}
