//! `--where` predicates over pair rows: `status = 'ok' and overlap_source >= 0.3 or scene != 'a'`.
//!
//! Grammar (keywords case-insensitive, `and` binds tighter than `or`):
//!
//! ```text
//! expr    := and ( "or" and )*
//! and     := primary ( "and" primary )*
//! primary := "(" expr ")" | column op literal
//! op      := "=" | "==" | "!=" | "<>" | "<" | "<=" | ">" | ">="
//! literal := 'text' (a quote doubled inside) | "text" | number
//! ```
//!
//! Text columns take text literals (compared as strings), numeric columns numbers. Errors name the
//! unknown column or the bad token and its position, under the field `--where`.

use crate::error::{Error, Result};
use super::tokens::{tokenize, Tok};
use crate::shards::row::{PairRow, Status};

/// The columns a predicate can test, with their names in the language.
pub const COLUMNS: &[(&str, Column)] = &[
    ("status", Column::Status),
    ("scene", Column::Scene),
    ("frame_key", Column::FrameKey),
    ("pair_key", Column::PairKey),
    ("overlap_source", Column::OverlapSource),
    ("overlap_target", Column::OverlapTarget),
    ("sample_index", Column::SampleIndex),
    ("unit_index", Column::UnitIndex),
    ("n_source_points", Column::NSourcePoints),
    ("n_target_points", Column::NTargetPoints),
];

/// A row field a predicate compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    Status,
    Scene,
    FrameKey,
    PairKey,
    OverlapSource,
    OverlapTarget,
    SampleIndex,
    UnitIndex,
    NSourcePoints,
    NTargetPoints,
}

/// A comparison operator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
}

/// A literal of a comparison.
#[derive(Clone, Debug, PartialEq)]
pub enum Literal {
    Text(String),
    Number(f64),
}

/// A parsed predicate; [`Filter::All`] matches every row.
#[derive(Clone, Debug, PartialEq)]
pub enum Filter {
    All,
    Compare(Column, Op, Literal),
    And(Box<Filter>, Box<Filter>),
    Or(Box<Filter>, Box<Filter>),
}

impl Column {
    fn name(self) -> &'static str {
        COLUMNS.iter().find(|(_, c)| *c == self).map(|(n, _)| *n).expect("every column is listed")
    }

    fn is_text(self) -> bool {
        matches!(self, Column::Status | Column::Scene | Column::FrameKey | Column::PairKey)
    }

    fn text(self, row: &PairRow) -> &str {
        match self {
            Column::Status => row.status.as_str(),
            Column::Scene => &row.scene,
            Column::FrameKey => &row.frame_key,
            _ => &row.pair_key,
        }
    }

    fn number(self, row: &PairRow) -> f64 {
        match self {
            Column::OverlapSource => row.overlap_source,
            Column::OverlapTarget => row.overlap_target,
            Column::SampleIndex => row.sample_index as f64,
            Column::UnitIndex => row.unit_index as f64,
            Column::NSourcePoints => row.source_points.len() as f64,
            _ => row.target_points.len() as f64,
        }
    }
}

impl Op {
    fn test<T: PartialOrd + ?Sized>(self, a: &T, b: &T) -> bool {
        match self {
            Op::Eq => a == b,
            Op::Ne => a != b,
            Op::Lt => a < b,
            Op::Le => a <= b,
            Op::Gt => a > b,
            Op::Ge => a >= b,
        }
    }
}

impl Filter {
    /// Parses a predicate; an empty or blank text gives [`Filter::All`].
    pub fn parse(text: &str) -> Result<Filter> {
        let tokens = tokenize(text)?;
        if tokens.is_empty() {
            return Ok(Filter::All);
        }
        let mut p = Parser { tokens, pos: 0 };
        let f = p.or()?;
        match p.tokens.get(p.pos) {
            None => Ok(f),
            Some((at, t)) => Err(bad(format!("unexpected {} at position {at}: expected `and`, `or` or the end", t.show()))),
        }
    }

    /// Parses `Some(text)`, or gives [`Filter::All`] for `None`.
    pub fn parse_opt(text: Option<&str>) -> Result<Filter> {
        text.map_or(Ok(Filter::All), Filter::parse)
    }

    /// Whether `row` satisfies the predicate.
    pub fn matches(&self, row: &PairRow) -> bool {
        match self {
            Filter::All => true,
            Filter::Compare(c, op, Literal::Text(s)) => op.test(c.text(row), s.as_str()),
            Filter::Compare(c, op, Literal::Number(v)) => op.test(&c.number(row), v),
            Filter::And(a, b) => a.matches(row) && b.matches(row),
            Filter::Or(a, b) => a.matches(row) || b.matches(row),
        }
    }
}

fn bad(message: String) -> Error {
    Error::config("--where", message)
}

struct Parser {
    tokens: Vec<(usize, Tok)>,
    pos: usize,
}

impl Parser {
    fn keyword(&mut self, word: &str) -> bool {
        match self.tokens.get(self.pos) {
            Some((_, Tok::Ident(s))) if s.eq_ignore_ascii_case(word) => {
                self.pos += 1;
                true
            }
            _ => false,
        }
    }

    fn next(&mut self, expected: &str) -> Result<(usize, Tok)> {
        let t = self.tokens.get(self.pos).cloned().ok_or_else(|| bad(format!("unexpected end: expected {expected}")))?;
        self.pos += 1;
        Ok(t)
    }

    fn or(&mut self) -> Result<Filter> {
        let mut f = self.and()?;
        while self.keyword("or") {
            f = Filter::Or(Box::new(f), Box::new(self.and()?));
        }
        Ok(f)
    }

    fn and(&mut self) -> Result<Filter> {
        let mut f = self.primary()?;
        while self.keyword("and") {
            f = Filter::And(Box::new(f), Box::new(self.primary()?));
        }
        Ok(f)
    }

    fn primary(&mut self) -> Result<Filter> {
        let (at, tok) = self.next("a column name or `(`")?;
        let name = match tok {
            Tok::Open => {
                let f = self.or()?;
                return match self.next("`)`")? {
                    (_, Tok::Close) => Ok(f),
                    (at, t) => Err(bad(format!("unexpected {} at position {at}: expected `)`", t.show()))),
                };
            }
            Tok::Ident(name) => name,
            t => return Err(bad(format!("unexpected {} at position {at}: expected a column name or `(`", t.show()))),
        };
        let column = COLUMNS.iter().find(|(n, _)| n.eq_ignore_ascii_case(&name)).map(|(_, c)| *c).ok_or_else(|| {
            let names: Vec<&str> = COLUMNS.iter().map(|(n, _)| *n).collect();
            bad(format!("unknown column `{name}` at position {at} (columns: {})", names.join(", ")))
        })?;
        let op = match self.next("a comparison operator")? {
            (_, Tok::Op(op)) => op,
            (at, t) => return Err(bad(format!("unexpected {} at position {at}: expected a comparison (=, !=, <, <=, >, >=) after `{name}`", t.show()))),
        };
        let literal = match (self.next("a value")?, column.is_text()) {
            ((at, Tok::Text(s)), true) => {
                if column == Column::Status && Status::parse(&s).is_none() {
                    return Err(bad(format!("unknown status '{s}' at position {at} (ok, low_overlap, too_few_points, input_error)")));
                }
                Literal::Text(s)
            }
            ((_, Tok::Number(v)), false) => Literal::Number(v),
            ((at, t), text) => {
                let want = if text { "a quoted text such as 'ok'" } else { "a number" };
                return Err(bad(format!("column `{}` compares with {want}; found {} at position {at}", column.name(), t.show())));
            }
        };
        Ok(Filter::Compare(column, op, literal))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(status: Status, scene: &str, ov: f64, n: usize) -> PairRow {
        let mut r = crate::export::tests_support::empty_row();
        r.status = status;
        r.scene = scene.into();
        r.overlap_source = ov;
        r.source_points = vec![crate::geometry::Point::origin(); n];
        r
    }

    #[test]
    fn parses_and_evaluates_with_precedence() {
        let f = Filter::parse("status = 'ok' and overlap_source >= 0.3 or scene = 'b'").unwrap();
        assert!(f.matches(&row(Status::Ok, "a", 0.3, 0)));
        assert!(!f.matches(&row(Status::Ok, "a", 0.29, 0)));
        assert!(f.matches(&row(Status::LowOverlap, "b", 0.0, 0)));
        let g = Filter::parse("STATUS == \"ok\" AND (scene = 'a' or scene='b') and n_source_points > 2").unwrap();
        assert!(g.matches(&row(Status::Ok, "b", 0.0, 3)));
        assert!(!g.matches(&row(Status::Ok, "c", 0.0, 3)));
        assert!(!g.matches(&row(Status::Ok, "a", 0.0, 2)));
        assert_eq!(Filter::parse("  ").unwrap(), Filter::All);
        assert!(Filter::parse("scene <> 'it''s'").unwrap().matches(&row(Status::Ok, "a", 0.0, 0)));
        assert!(Filter::parse("overlap_source < -1e-3").unwrap().matches(&row(Status::Ok, "a", -0.5, 0)));
    }

    #[test]
    fn errors_name_the_column_or_token() {
        let e = |s: &str| Filter::parse(s).unwrap_err().to_string();
        assert!(e("overlap > 0.3").contains("unknown column `overlap`"), "{}", e("overlap > 0.3"));
        assert!(e("status = ok").contains("quoted text"));
        assert!(e("overlap_source = 'x'").contains("a number"));
        assert!(e("status = 'fine'").contains("unknown status 'fine'"));
        assert!(e("status = 'ok' and").contains("unexpected end"));
        assert!(e("(status = 'ok'").contains("expected `)`"));
        assert!(e("status = 'ok' scene").contains("`scene` at position 14"));
        assert!(e("scene ~ 'a'").contains("unexpected character `~`"));
        assert!(e("scene = 'a").contains("unterminated string"));
        assert!(e("x = 1").contains("--where"));
    }
}
