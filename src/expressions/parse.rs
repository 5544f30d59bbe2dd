//! Recursive-descent parser for the grammar in the module docs, with 1-based character columns
//! in every error.

use super::{diff, Expr, ExprError, Func, Node};
use std::collections::BTreeMap;

/// Deepest nesting of parentheses, calls and unary signs accepted.
const MAX_NESTING: usize = 200;
/// Most tokens accepted (keeps trees shallow enough for recursive evaluation).
const MAX_TOKENS: usize = 10_000;
/// Longest expression text parsed (bytes): room for [`MAX_TOKENS`] tokens of 100 bytes each.
const MAX_SOURCE_BYTES: usize = 100 * MAX_TOKENS;
/// Largest accepted `|n|` in `u^n`.
const MAX_EXPONENT: i64 = 1 << 20;
/// Functions offered in messages (the derivative-only ones are accepted but not advertised).
const USER_FUNCTIONS: usize = 11;

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    /// A number; `true` when written with digits only.
    Num(f64, bool),
    Name(String),
    Sym(char),
}

#[derive(Clone, Debug)]
struct Token {
    tok: Tok,
    col: usize,
    text: String,
}

fn err<T>(column: usize, message: impl Into<String>) -> Result<T, ExprError> {
    Err(ExprError {
        column,
        message: message.into(),
    })
}

fn lex(src: &str) -> Result<Vec<Token>, ExprError> {
    let chars: Vec<char> = src.chars().collect();
    let digits_from = |mut j: usize| {
        while j < chars.len() && chars[j].is_ascii_digit() {
            j += 1;
        }
        j
    };
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let (c, col) = (chars[i], i + 1);
        let start = i;
        let tok = if c.is_whitespace() {
            i += 1;
            continue;
        } else if c.is_ascii_digit() || c == '.' {
            i = digits_from(i);
            let int_end = i;
            if chars.get(i) == Some(&'.') {
                i = digits_from(i + 1);
            }
            if matches!(chars.get(i), Some('e' | 'E')) {
                let sign = usize::from(matches!(chars.get(i + 1), Some('+' | '-')));
                if chars.get(i + 1 + sign).is_some_and(char::is_ascii_digit) {
                    i = digits_from(i + 1 + sign);
                }
            }
            let text: String = chars[start..i].iter().collect();
            let Ok(value) = text.parse::<f64>() else {
                return err(col, format!("malformed number `{text}`"));
            };
            if !value.is_finite() {
                return err(col, format!("number `{text}` is out of range"));
            }
            Tok::Num(value, int_end == i)
        } else if c.is_alphabetic() || c == '_' {
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            Tok::Name(chars[start..i].iter().collect())
        } else if "+-*/^(),".contains(c) {
            i += 1;
            Tok::Sym(c)
        } else {
            return err(col, format!("unexpected character `{c}`"));
        };
        let text = chars[start..i].iter().collect();
        tokens.push(Token { tok, col, text });
    }
    Ok(tokens)
}

struct Parser<'a> {
    tokens: Vec<Token>,
    pos: usize,
    end_col: usize,
    nesting: usize,
    variables: &'a [String],
    parameters: &'a BTreeMap<String, f64>,
}

/// Parses `src` over `variables` (`variables[i]` becomes `x_i`) and `parameters` (which become
/// constants; a name is looked up as a variable first, then as a parameter, then as `pi`).
/// Constant subexpressions fold when the `f64` result is exact.
pub fn parse(
    src: &str,
    variables: &[String],
    parameters: &BTreeMap<String, f64>,
) -> Result<Expr, ExprError> {
    // Refused before lexing: a generated file's 90 MB expression took 16 s and a 370 MB
    // character buffer to be counted.
    if src.len() > MAX_SOURCE_BYTES {
        return err(
            1,
            format!(
                "expression too long ({} bytes; at most {MAX_SOURCE_BYTES})",
                src.len()
            ),
        );
    }
    let tokens = lex(src)?;
    if tokens.is_empty() {
        return err(1, "empty expression");
    }
    if tokens.len() > MAX_TOKENS {
        return err(1, format!("expression too long (over {MAX_TOKENS} tokens)"));
    }
    let mut p = Parser {
        tokens,
        pos: 0,
        end_col: src.chars().count() + 1,
        nesting: 0,
        variables,
        parameters,
    };
    let node = p.expr()?;
    match p.peek() {
        None => Ok(Expr::of(node)),
        Some(t) if t.tok == Tok::Sym(')') => {
            err(t.col, "unbalanced parenthesis: `)` without a matching `(`")
        }
        Some(t) => err(
            t.col,
            format!("unexpected `{}` after a complete expression", t.text),
        ),
    }
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.pos)
    }

    fn next(&mut self) -> Option<Token> {
        let t = self.tokens.get(self.pos).cloned();
        self.pos += 1;
        t
    }

    /// Consumes the next token if it is the symbol `c`.
    fn eat(&mut self, c: char) -> bool {
        let hit = self.peek().is_some_and(|t| t.tok == Tok::Sym(c));
        if hit {
            self.pos += 1;
        }
        hit
    }

    /// Consumes and returns the next symbol if it is one of `cs`.
    fn eat_any(&mut self, cs: &[char]) -> Option<char> {
        let c = cs.iter().copied().find(|&c| self.eat(c));
        c
    }

    fn enter(&mut self, col: usize) -> Result<(), ExprError> {
        self.nesting += 1;
        if self.nesting > MAX_NESTING {
            return err(
                col,
                format!("expression nested too deeply (over {MAX_NESTING})"),
            );
        }
        Ok(())
    }

    fn expr(&mut self) -> Result<Node, ExprError> {
        let mut node = self.term()?;
        while let Some(op) = self.eat_any(&['+', '-']) {
            let rhs = self.term()?;
            node = diff::fold(if op == '+' {
                Node::Add(Box::new(node), Box::new(rhs))
            } else {
                Node::Sub(Box::new(node), Box::new(rhs))
            });
        }
        Ok(node)
    }

    fn term(&mut self) -> Result<Node, ExprError> {
        let mut node = self.unary()?;
        while let Some(op) = self.eat_any(&['*', '/']) {
            let rhs = self.unary()?;
            node = diff::fold(if op == '*' {
                Node::Mul(Box::new(node), Box::new(rhs))
            } else {
                Node::Div(Box::new(node), Box::new(rhs))
            });
        }
        Ok(node)
    }

    fn unary(&mut self) -> Result<Node, ExprError> {
        let col = self.peek().map_or(self.end_col, |t| t.col);
        let Some(op) = self.eat_any(&['-', '+']) else {
            return self.power();
        };
        self.enter(col)?;
        let inner = self.unary()?;
        self.nesting -= 1;
        Ok(if op == '-' {
            diff::fold(Node::Neg(Box::new(inner)))
        } else {
            inner
        })
    }

    fn power(&mut self) -> Result<Node, ExprError> {
        let base = self.primary()?;
        if !self.eat('^') {
            return Ok(base);
        }
        let col = self.peek().map_or(self.end_col, |t| t.col);
        let n = self.exponent()?;
        match i32::try_from(n) {
            Ok(n) if n.unsigned_abs() as i64 <= MAX_EXPONENT => {
                Ok(diff::fold(Node::Pow(Box::new(base), n)))
            }
            _ => err(
                col,
                format!("exponent {n} is out of range (|n| ≤ {MAX_EXPONENT})"),
            ),
        }
    }

    /// `("-" | "+")? INTEGER ("^" exponent)?`, evaluated (right-associative).
    fn exponent(&mut self) -> Result<i64, ExprError> {
        let negative = self.eat_any(&['-', '+']) == Some('-');
        let col = self.peek().map_or(self.end_col, |t| t.col);
        let base = match self.next() {
            Some(Token {
                tok: Tok::Num(v, true),
                ..
            }) if v <= MAX_EXPONENT as f64 => v as i64,
            Some(Token {
                tok: Tok::Num(_, true),
                ..
            }) => {
                return err(
                    col,
                    format!("exponent is out of range (|n| ≤ {MAX_EXPONENT})"),
                )
            }
            _ => return err(col, "exponent must be an integer literal; use sqrt(…)"),
        };
        let base = if negative { -base } else { base };
        if !self.eat('^') {
            return Ok(base);
        }
        let col_e = self.peek().map_or(self.end_col, |t| t.col);
        let e = self.exponent()?;
        u32::try_from(e)
            .ok()
            .and_then(|e| base.checked_pow(e))
            .filter(|v| v.abs() <= MAX_EXPONENT)
            .map_or_else(
                || err(col_e, format!("exponent must be an integer literal; `{base}^{e}` is not a small integer")),
                Ok,
            )
    }

    fn primary(&mut self) -> Result<Node, ExprError> {
        let Some(t) = self.next() else {
            return err(
                self.end_col,
                "unexpected end of input; expected a number, a name or `(`",
            );
        };
        match t.tok {
            Tok::Num(v, _) => Ok(Node::Const(v)),
            Tok::Name(name) if self.peek().is_some_and(|n| n.tok == Tok::Sym('(')) => {
                self.call(&name, t.col)
            }
            Tok::Name(name) => self.symbol(&name, t.col),
            Tok::Sym('(') => {
                self.enter(t.col)?;
                let inner = self.expr()?;
                self.nesting -= 1;
                self.close(t.col)?;
                Ok(inner)
            }
            Tok::Sym(_) => err(
                t.col,
                format!("unexpected `{}`; expected a number, a name or `(`", t.text),
            ),
        }
    }

    /// Consumes the `)` matching the `(` at `open`.
    fn close(&mut self, open: usize) -> Result<(), ExprError> {
        match self.next() {
            Some(t) if t.tok == Tok::Sym(')') => Ok(()),
            None => err(open, "unbalanced parenthesis: `(` is never closed"),
            Some(t) => err(t.col, format!("unexpected `{}`; expected `)`", t.text)),
        }
    }

    fn symbol(&self, name: &str, col: usize) -> Result<Node, ExprError> {
        if let Some(i) = self.variables.iter().position(|v| v == name) {
            return Ok(Node::Var(i));
        }
        if let Some(&value) = self.parameters.get(name) {
            if !value.is_finite() {
                return err(col, format!("parameter `{name}` = {value} is not finite"));
            }
            return Ok(Node::Const(value));
        }
        if name == "pi" {
            return Ok(Node::Const(std::f64::consts::PI));
        }
        let known: Vec<&str> = self
            .variables
            .iter()
            .chain(self.parameters.keys())
            .map(String::as_str)
            .chain(["pi"])
            .collect();
        err(
            col,
            format!(
                "unknown symbol `{name}`; known symbols: {}",
                known.join(", ")
            ),
        )
    }

    fn call(&mut self, name: &str, col: usize) -> Result<Node, ExprError> {
        let Some(func) = Func::from_name(name) else {
            if self.variables.iter().any(|v| v == name) || self.parameters.contains_key(name) {
                return err(
                    col,
                    format!("`{name}` is not a function (write `{name}*(…)` for a product)"),
                );
            }
            let known: Vec<&str> = Func::ALL[..USER_FUNCTIONS]
                .iter()
                .map(|f| f.name())
                .collect();
            return err(
                col,
                format!(
                    "unknown function `{name}`; known functions: {}",
                    known.join(", ")
                ),
            );
        };
        let open = self.next().map_or(col, |t| t.col);
        self.enter(open)?;
        let mut args = Vec::new();
        if !self.eat(')') {
            loop {
                args.push(self.expr()?);
                if self.eat(',') {
                    continue;
                }
                self.close(open)?;
                break;
            }
        }
        self.nesting -= 1;
        if args.len() != func.arity() {
            let plural = if func.arity() == 1 { "" } else { "s" };
            return err(
                col,
                format!(
                    "function `{name}` takes {} argument{plural}, found {}",
                    func.arity(),
                    args.len()
                ),
            );
        }
        Ok(diff::fold(Node::Call(func, args)))
    }
}
