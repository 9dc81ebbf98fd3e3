//! Text that came from outside (a device's HELLO strings, a file's cells,
//! an error chain) made safe and short enough to print: control and
//! bidirectional-override characters escaped, length bounded.

/// Characters shown of an untrusted string by default.
pub const DEFAULT_MAX_CHARS: usize = 200;

/// Whether `c` may not reach a terminal as is: C0/C1 controls (escape
/// sequences, carriage returns, bells) and the Unicode bidirectional
/// controls that reorder what a reader sees.
fn is_unsafe(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// `s` with every unsafe character escaped (`\u{1b}`, `\n`, …) and cut
/// after `max_chars` characters, the cut marked with how much was left
/// out (`… (20000 more characters)`).
pub fn printable(s: &str, max_chars: usize) -> String {
    let mut out = String::with_capacity(s.len().min(4 * max_chars + 32));
    let mut chars = s.chars();
    for (shown, c) in chars.by_ref().enumerate() {
        if shown == max_chars {
            let rest = 1 + chars.count();
            out.push_str(&format!("… ({rest} more characters)"));
            return out;
        }
        if is_unsafe(c) {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controls_are_escaped_and_long_text_cut() {
        assert_eq!(
            printable("DAQ\u{1b}[2J\r\u{7}", 50),
            "DAQ\\u{1b}[2J\\r\\u{7}"
        );
        assert_eq!(printable("a\u{202e}b", 50), "a\\u{202e}b");
        assert_eq!(printable("plain", 50), "plain");
        let long = "x".repeat(20_000);
        let p = printable(&long, 10);
        assert_eq!(p, format!("{}… (19990 more characters)", "x".repeat(10)));
        assert_eq!(printable(&"é".repeat(10), 10), "é".repeat(10));
    }
}
