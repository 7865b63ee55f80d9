//! Configuration files (run recipe, dwell case, spot manifest, `[vibration]` table) read with
//! serde into typed structs, strictly: every struct denies unknown fields, and this module turns
//! serde's and the TOML parser's errors into one-line messages that name the key with its
//! table and, for a misspelt name, the nearest valid one (Levenshtein distance):
//!
//! - unknown key: key `[process] pich`, "unknown key; did you mean `pitch_mm`? (line 12)";
//! - unknown table: key `[proces]`, "unknown table; did you mean [process]? (line 9)";
//! - wrong type: key `[path] pitch_mm`, "expected a number, found string \"3\" (line 4)";
//! - TOML syntax: key `TOML`, "<the parser's cause> at line 3, column 7".
//!
//! Callers wrap the [`ConfigError`] in their own error type with the file name, so a message
//! reads `run.toml: [process] pich: unknown key; did you mean `pitch_mm`? (line 12)`.

use serde::de::DeserializeOwned;

/// A configuration error: the key (with its table, as `[table] key`, `[table]` or `TOML`) and
/// what is wrong with it. One line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    pub key: String,
    pub what: String,
}

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.key, self.what)
    }
}

impl std::error::Error for ConfigError {}

/// Longest run of non-blank characters a message echoes whole (a key or value of a million
/// characters is cut to its start and its length, so the message stays one readable line).
const MAX_ECHOED_CHARS: usize = 64;
/// Characters of an unknown name compared with the valid ones (the comparison costs the
/// name's length times the candidates' squared: a million-character key took seconds).
const MAX_COMPARED_CHARS: usize = 64;

impl ConfigError {
    /// The error with every over-long word of its key and message cut (see
    /// [`MAX_ECHOED_CHARS`]).
    fn shortened(self) -> ConfigError {
        ConfigError {
            key: shorten(&self.key),
            what: shorten(&self.what),
        }
    }
}

/// `s` with each run of non-blank characters longer than [`MAX_ECHOED_CHARS`] cut to its
/// first 40 characters and its length: `"xxxx...` -> `"xxxx…(1000002 characters)`.
fn shorten(s: &str) -> String {
    if s.len() <= MAX_ECHOED_CHARS {
        return s.to_string();
    }
    let mut out = String::with_capacity(s.len().min(1024));
    for (i, word) in s.split(' ').enumerate() {
        if i > 0 {
            out.push(' ');
        }
        let n = word.chars().count();
        if n > MAX_ECHOED_CHARS {
            out.extend(word.chars().take(40));
            out.push_str(&format!("…({n} characters)"));
        } else {
            out.push_str(word);
        }
    }
    out
}

/// Levenshtein edit distance (insertions, deletions, substitutions), by characters.
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0; b.len() + 1];
    for (i, ca) in a.chars().enumerate() {
        cur[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

/// The candidate nearest to `name` (ties: the first listed): the smallest edit distance to
/// one of the candidate's prefixes, then the fewest characters left out, so a name typed short
/// (`pich` for `pitch_mm`, `k1` for `k1_n_per_mm`) is matched by its start rather than by an
/// unrelated short name.
pub fn nearest<'a>(name: &str, candidates: &[&'a str]) -> Option<&'a str> {
    let name: String = name.chars().take(MAX_COMPARED_CHARS).collect();
    let name = name.as_str();
    let score = |c: &str| -> (usize, usize) {
        let chars: Vec<(usize, char)> = c.char_indices().collect();
        (0..=chars.len())
            .map(|k| {
                let end = chars.get(k).map_or(c.len(), |&(i, _)| i);
                (edit_distance(name, &c[..end]), chars.len() - k)
            })
            .min()
            .unwrap_or((usize::MAX, usize::MAX))
    };
    candidates.iter().min_by_key(|c| score(c)).copied()
}

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// The backtick-quoted words of a serde message (`unknown field `x`, expected `a` or `b``).
fn quoted(msg: &str) -> Vec<&str> {
    msg.split('`').skip(1).step_by(2).collect()
}

/// The dotted table the byte `offset` of `text` lies in, and whether it lies in a table header
/// (`[a.b]` / `[[a]]`): the last header before it, plus inline tables opened on its line.
fn table_at(text: &str, offset: usize) -> (String, bool) {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line = &text[line_start..];
    let trimmed = line.trim_start();
    let header = |l: &str| -> Option<String> {
        let l = l.trim();
        if !l.starts_with('[') {
            return None;
        }
        let inner = l.trim_start_matches('[');
        let end = inner.find(']')?;
        Some(
            inner[..end]
                .split('.')
                .map(|s| s.trim().trim_matches('"'))
                .collect::<Vec<_>>()
                .join("."),
        )
    };
    if trimmed.starts_with('[') {
        // The unknown name is a segment of this header: its table is the header up to it.
        let col = offset - line_start;
        let name_end = line[col..].find(['.', ']']).map_or(line.len(), |i| col + i);
        let upto = line[..name_end]
            .trim()
            .trim_start_matches('[')
            .split('.')
            .map(|s| s.trim().trim_matches('"'))
            .collect::<Vec<_>>();
        let parent = upto[..upto.len().saturating_sub(1)].join(".");
        return (parent, true);
    }
    let mut table = text[..line_start]
        .lines()
        .rev()
        .find_map(header)
        .unwrap_or_default();
    // Inline tables opened before the offset on this line: `model = { kind = ...`.
    let mut depth_names: Vec<String> = Vec::new();
    let head = &text[line_start..offset];
    let mut last_key = String::new();
    let mut tok = String::new();
    for c in head.chars() {
        match c {
            '=' => last_key = tok.trim().trim_matches('"').to_string(),
            '{' => depth_names.push(last_key.clone()),
            '}' => {
                depth_names.pop();
            }
            ',' => tok.clear(),
            _ => {}
        }
        if c == '=' || c == '{' || c == ',' {
            tok.clear();
        } else {
            tok.push(c);
        }
    }
    for n in depth_names {
        if !table.is_empty() {
            table.push('.');
        }
        table.push_str(&n);
    }
    (table, false)
}

/// The key whose value starts at byte `offset` (the name before the nearest `=`).
fn key_before(text: &str, offset: usize) -> String {
    let head = &text[..offset.min(text.len())];
    let Some(eq) = head.rfind('=') else {
        return String::new();
    };
    let before = head[..eq].trim_end();
    let start = before
        .rfind(|c: char| !(c.is_alphanumeric() || c == '_' || c == '-' || c == '"' || c == '.'))
        .map_or(0, |i| i + 1);
    before[start..].trim_matches('"').to_string()
}

fn table_label(table: &str) -> String {
    if table.is_empty() {
        "top level".to_string()
    } else {
        format!("[{table}]")
    }
}

/// Nicer names for serde's expected types.
fn expected(e: &str) -> String {
    match e {
        "f64" | "f32" => "a number".into(),
        "u8" | "u16" | "u32" | "u64" | "usize" | "i32" | "i64" | "isize" => "an integer".into(),
        "a string" | "string" => "a string".into(),
        "a boolean" | "bool" => "true or false".into(),
        s if s.starts_with("struct ") => "a table".into(),
        s if s.starts_with("a sequence") => "an array".into(),
        s => s.to_string(),
    }
}

/// Reads TOML `text` into `T` (whose structs deny unknown fields); errors as in the module doc.
pub fn from_toml<T: DeserializeOwned>(text: &str) -> Result<T, ConfigError> {
    from_toml_inner(text).map_err(ConfigError::shortened)
}

fn from_toml_inner<T: DeserializeOwned>(text: &str) -> Result<T, ConfigError> {
    if let Err(e) = text.parse::<toml::Table>() {
        let at = e
            .span()
            .map(|s| {
                let (l, c) = line_col(text, s.start);
                format!(" at line {l}, column {c}")
            })
            .unwrap_or_default();
        return Err(ConfigError {
            key: "TOML".into(),
            what: format!("syntax error: {}{at}", one_line(e.message())),
        });
    }
    toml::from_str::<T>(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        let (line, col) = line_col(text, span.start);
        explain(e.message(), text, span.start, line, col)
    })
}

fn one_line(s: &str) -> String {
    s.trim().replace('\n', " ")
}

fn explain(msg: &str, text: &str, offset: usize, line: usize, col: usize) -> ConfigError {
    let msg = one_line(msg);
    let (table, in_header) = table_at(text, offset);
    let at_line = format!("(line {line})");
    if let Some(rest) = msg.strip_prefix("unknown field ") {
        let names = quoted(rest);
        let unknown = names.first().copied().unwrap_or("");
        let valid = &names[1.min(names.len())..];
        let is_table = in_header
            || (table.is_empty() && {
                // `proces.x = 1` or an inline table at the top level.
                text.parse::<toml::Table>()
                    .ok()
                    .and_then(|t| t.get(unknown).map(|v| v.is_table()))
                    .unwrap_or(false)
            });
        let prefix = if table.is_empty() {
            String::new()
        } else {
            format!("{table}.")
        };
        return if is_table {
            let hint = nearest(unknown, valid)
                .map(|n| format!("; did you mean [{prefix}{n}]?"))
                .unwrap_or_default();
            ConfigError {
                key: format!("[{prefix}{unknown}]"),
                what: format!("unknown table{hint} {at_line}"),
            }
        } else {
            let hint = match nearest(unknown, valid) {
                Some(n) => format!("; did you mean `{n}`?"),
                None => " (this table takes no keys)".into(),
            };
            let key = if table.is_empty() {
                unknown.to_string()
            } else {
                format!("[{table}] {unknown}")
            };
            ConfigError {
                key,
                what: format!("unknown key{hint} {at_line}"),
            }
        };
    }
    let key = key_before(text, offset);
    let key = match (table.is_empty(), key.is_empty()) {
        (_, true) => table_label(&table),
        (true, false) => key,
        (false, false) => format!("[{table}] {key}"),
    };
    if let Some(rest) = msg.strip_prefix("invalid type: ") {
        if let Some((found, exp)) = rest.split_once(", expected ") {
            return ConfigError {
                key,
                what: format!("expected {}, found {found} {at_line}", expected(exp)),
            };
        }
    }
    if let Some(rest) = msg.strip_prefix("unknown variant ") {
        let names = quoted(rest);
        let unknown = names.first().copied().unwrap_or("");
        let valid = &names[1.min(names.len())..];
        let hint = nearest(unknown, valid)
            .map(|n| format!("; did you mean \"{n}\"?"))
            .unwrap_or_default();
        return ConfigError {
            key,
            what: format!("unknown value \"{unknown}\"{hint} {at_line}"),
        };
    }
    ConfigError {
        key,
        what: format!("{msg} at line {line}, column {col}"),
    }
}

/// Reads an already-parsed table (named `table`, e.g. `vibration`) into `T`, whose fields must
/// all be optional: a failure is traced to the first key that fails on its own, so the error
/// names it (the table was parsed elsewhere, so there is no line).
pub fn from_table<T: DeserializeOwned>(table: &toml::Table, name: &str) -> Result<T, ConfigError> {
    from_table_inner(table, name).map_err(ConfigError::shortened)
}

fn from_table_inner<T: DeserializeOwned>(
    table: &toml::Table,
    name: &str,
) -> Result<T, ConfigError> {
    let whole = toml::Value::Table(table.clone()).try_into::<T>();
    let err = match whole {
        Ok(v) => return Ok(v),
        Err(e) => e,
    };
    for (k, v) in table {
        let mut one = toml::Table::new();
        one.insert(k.clone(), v.clone());
        if let Err(e) = toml::Value::Table(one).try_into::<T>() {
            let msg = one_line(e.message());
            if let Some(rest) = msg.strip_prefix("unknown field ") {
                let names = quoted(rest);
                let valid = &names[1.min(names.len())..];
                let hint = match nearest(k, valid) {
                    Some(n) => format!("; did you mean `{n}`?"),
                    None => " (this table takes no keys)".into(),
                };
                return Err(ConfigError {
                    key: format!("[{name}] {k}"),
                    what: format!("unknown key{hint}"),
                });
            }
            let what = match msg
                .strip_prefix("invalid type: ")
                .and_then(|r| r.split_once(", expected "))
            {
                Some((found, exp)) => format!("expected {}, found {found}", expected(exp)),
                None => msg,
            };
            return Err(ConfigError {
                key: format!("[{name}] {k}"),
                what,
            });
        }
    }
    Err(ConfigError {
        key: format!("[{name}]"),
        what: one_line(err.message()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Model {
        kind: String,
        sigma_mm: Option<f64>,
    }
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct PathT {
        log: String,
        pitch_mm: Option<f64>,
    }
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Tif {
        model: Option<Model>,
        spot: Option<String>,
    }
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Doc {
        path: Option<PathT>,
        tif: Option<Tif>,
        spot: Option<Vec<PathT>>,
    }

    fn err(t: &str) -> String {
        from_toml::<Doc>(t).unwrap_err().to_string()
    }

    #[test]
    fn integers_are_numbers() {
        let d: Doc = from_toml("[path]\nlog = \"a\"\npitch_mm = 3\n").unwrap();
        assert_eq!(d.path.unwrap().pitch_mm, Some(3.0));
    }

    #[test]
    fn distance_and_nearest() {
        assert_eq!(edit_distance("pich", "pitch_mm"), 4);
        assert_eq!(edit_distance("", "abc"), 3);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(
            nearest("proces", &["path", "process", "tif"]),
            Some("process")
        );
        assert_eq!(nearest("x", &[]), None);
    }

    #[test]
    fn messages_name_table_key_and_nearest_name() {
        assert_eq!(
            err("[path]\nlog = \"a\"\npich = 3\n"),
            "[path] pich: unknown key; did you mean `pitch_mm`? (line 3)"
        );
        assert_eq!(
            err("[pth]\nlog = \"a\"\n"),
            "[pth]: unknown table; did you mean [path]? (line 1)"
        );
        assert_eq!(
            err("[path]\nlog = \"a\"\npitch_mm = \"3\"\n"),
            "[path] pitch_mm: expected a number, found string \"3\" (line 3)"
        );
        assert_eq!(
            err("[tif]\nmodel = { kind = \"g\", sigmma = 1.0 }\n"),
            "[tif.model] sigmma: unknown key; did you mean `sigma_mm`? (line 2)"
        );
        assert_eq!(
            err("[tif.modle]\nkind = \"g\"\n"),
            "[tif.modle]: unknown table; did you mean [tif.model]? (line 1)"
        );
        assert_eq!(
            err("[[spot]]\nlog = \"a\"\n[[spot]]\nlog = \"b\"\nlgo = 1\n"),
            "[spot] lgo: unknown key; did you mean `log`? (line 5)"
        );
        assert_eq!(
            err("tif = 3\n"),
            "tif: expected a table, found integer `3` (line 1)"
        );
        let e = err("[path]\nlog = \"a\"\npitch_mm = \n");
        assert!(
            e.starts_with("TOML: syntax error: ") && e.ends_with("at line 3, column 12"),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }

    #[test]
    fn tables_parsed_elsewhere_name_the_failing_key() {
        #[derive(Debug, Deserialize)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct V {
            fn_n: Option<f64>,
            mu: Option<f64>,
        }
        let t: toml::Table = "fn_n = 3.0\nmuu = 0.2\n".parse().unwrap();
        assert_eq!(
            from_table::<V>(&t, "vibration").unwrap_err().to_string(),
            "[vibration] muu: unknown key; did you mean `mu`?"
        );
        let t: toml::Table = "fn_n = 3.0\nmu = \"high\"\n".parse().unwrap();
        assert_eq!(
            from_table::<V>(&t, "vibration").unwrap_err().to_string(),
            "[vibration] mu: expected a number, found string \"high\""
        );
    }
}
