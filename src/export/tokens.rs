//! The tokenizer of `--where` predicates: identifiers, quoted texts, numbers, operators, parentheses.

use super::filter::Op;
use crate::error::{Error, Result};

fn bad(message: String) -> Error {
    Error::config("--where", message)
}

/// One token of a predicate.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Tok {
    Ident(String),
    Text(String),
    Number(f64),
    Op(Op),
    Open,
    Close,
}

impl Tok {
    pub(super) fn show(&self) -> String {
        match self {
            Tok::Ident(s) => format!("`{s}`"),
            Tok::Text(s) => format!("'{s}'"),
            Tok::Number(v) => format!("`{v}`"),
            Tok::Op(o) => {
                let sym = match o {
                    Op::Eq => "=",
                    Op::Ne => "!=",
                    Op::Lt => "<",
                    Op::Le => "<=",
                    Op::Gt => ">",
                    Op::Ge => ">=",
                };
                format!("operator `{sym}`")
            }
            Tok::Open => "`(`".into(),
            Tok::Close => "`)`".into(),
        }
    }
}

/// Splits the text into tokens, each with its character position (errors under the field `--where`).
pub(super) fn tokenize(text: &str) -> Result<Vec<(usize, Tok)>> {
    let chars: Vec<char> = text.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let (start, c) = (i, chars[i]);
        let next = chars.get(i + 1).copied();
        let tok = match c {
            c if c.is_whitespace() => {
                i += 1;
                continue;
            }
            '(' => Tok::Open,
            ')' => Tok::Close,
            '=' => {
                if next == Some('=') {
                    i += 1;
                }
                Tok::Op(Op::Eq)
            }
            '!' if next == Some('=') => { i += 1; Tok::Op(Op::Ne) }
            '<' if next == Some('=') => { i += 1; Tok::Op(Op::Le) }
            '<' if next == Some('>') => { i += 1; Tok::Op(Op::Ne) }
            '<' => Tok::Op(Op::Lt),
            '>' if next == Some('=') => { i += 1; Tok::Op(Op::Ge) }
            '>' => Tok::Op(Op::Gt),
            '\'' | '"' => {
                let mut s = String::new();
                i += 1;
                loop {
                    match chars.get(i) {
                        None => return Err(bad(format!("unterminated string starting at position {start}"))),
                        Some(&q) if q == c && chars.get(i + 1) == Some(&c) => { s.push(c); i += 2; }
                        Some(&q) if q == c => break,
                        Some(&ch) => { s.push(ch); i += 1; }
                    }
                }
                Tok::Text(s)
            }
            c if c.is_ascii_digit() || ((c == '-' || c == '+' || c == '.') && next.is_some_and(|n| n.is_ascii_digit() || n == '.')) => {
                let mut j = i + 1;
                while j < chars.len() && (chars[j].is_ascii_alphanumeric() || chars[j] == '.' || ((chars[j] == '-' || chars[j] == '+') && matches!(chars[j - 1], 'e' | 'E'))) {
                    j += 1;
                }
                let s: String = chars[i..j].iter().collect();
                let v = s.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| bad(format!("`{s}` at position {start} is not a number")))?;
                i = j - 1;
                Tok::Number(v)
            }
            c if c.is_alphabetic() || c == '_' => {
                let mut j = i + 1;
                while j < chars.len() && (chars[j].is_alphanumeric() || chars[j] == '_') {
                    j += 1;
                }
                let s: String = chars[i..j].iter().collect();
                i = j - 1;
                Tok::Ident(s)
            }
            other => return Err(bad(format!("unexpected character `{other}` at position {start}"))),
        };
        out.push((start, tok));
        i += 1;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_operators_texts_and_numbers() {
        let t: Vec<Tok> = tokenize("a<=-1.5e-3 and(b <> 'it''s')").unwrap().into_iter().map(|(_, t)| t).collect();
        assert_eq!(
            t,
            vec![
                Tok::Ident("a".into()),
                Tok::Op(Op::Le),
                Tok::Number(-1.5e-3),
                Tok::Ident("and".into()),
                Tok::Open,
                Tok::Ident("b".into()),
                Tok::Op(Op::Ne),
                Tok::Text("it's".into()),
                Tok::Close,
            ]
        );
        assert!(tokenize("x = 1.2.3").unwrap_err().to_string().contains("`1.2.3` at position 4 is not a number"));
    }
}
