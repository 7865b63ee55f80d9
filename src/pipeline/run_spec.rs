//! A run as the lab engineer names it on the command line: `NAME=B1[+B2...],A1[+A2...]`, one or
//! more before maps and one or more after maps (repeat measurements).

use std::path::PathBuf;

/// One run as given on the command line: a name and one or more maps before and after.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSpec {
    pub name: String,
    pub before: Vec<PathBuf>,
    pub after: Vec<PathBuf>,
}

impl RunSpec {
    /// Parses `NAME=B1[+B2...],A1[+A2...]`.
    pub fn parse(s: &str) -> Result<RunSpec, String> {
        let (name, files) = s
            .split_once('=')
            .ok_or_else(|| format!("run '{s}': expected NAME=BEFORE,AFTER"))?;
        let name = name.trim();
        if name.is_empty() {
            return Err(format!("run '{s}': the name before '=' is empty"));
        }
        let (b, a) = files
            .split_once(',')
            .ok_or_else(|| format!("run '{name}': expected BEFORE,AFTER after '='"))?;
        let list = |part: &str, what: &str| -> Result<Vec<PathBuf>, String> {
            let v: Vec<PathBuf> = part
                .split('+')
                .map(str::trim)
                .filter(|p| !p.is_empty())
                .map(PathBuf::from)
                .collect();
            if v.is_empty() {
                Err(format!("run '{name}': no {what} map given"))
            } else {
                Ok(v)
            }
        };
        Ok(RunSpec {
            name: name.to_string(),
            before: list(b, "before")?,
            after: list(a, "after")?,
        })
    }
}

/// `NAME=RECIPE.toml`: a run given by its recipe (one file after '=', ending in `.toml`).
/// None for any other form (see [`RunSpec::parse`]).
pub fn parse_recipe_run(s: &str) -> Option<(String, PathBuf)> {
    let (name, file) = s.split_once('=')?;
    let (name, file) = (name.trim(), file.trim());
    let is_recipe =
        !name.is_empty() && !file.contains(',') && file.to_ascii_lowercase().ends_with(".toml");
    is_recipe.then(|| (name.to_string(), PathBuf::from(file)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_spec_parsing() {
        let r = RunSpec::parse("orig=b.dat,a.dat").unwrap();
        assert_eq!(r.name, "orig");
        assert_eq!(r.before, vec![PathBuf::from("b.dat")]);
        assert_eq!(r.after, vec![PathBuf::from("a.dat")]);
        let r = RunSpec::parse("s=b1.dat+b2.dat,a1.dat+a2.dat+a3.dat").unwrap();
        assert_eq!(r.before.len(), 2);
        assert_eq!(r.after.len(), 3);
        assert!(RunSpec::parse("nobody").is_err());
        assert!(RunSpec::parse("=b,a").is_err());
        assert!(RunSpec::parse("x=b.dat").is_err());
        assert!(RunSpec::parse("x=,a.dat").is_err());
        assert_eq!(
            parse_recipe_run("orig=runs/a.toml"),
            Some(("orig".into(), PathBuf::from("runs/a.toml")))
        );
        assert_eq!(parse_recipe_run("orig=b.dat,a.dat"), None);
        assert_eq!(parse_recipe_run("=a.toml"), None);
    }
}
