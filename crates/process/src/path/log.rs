//! Reading tool-path logs: CSV with a header naming at least `t_s`, `x_mm`, `y_mm` (any order;
//! extra columns are ignored), time strictly increasing, every value finite. Errors name the
//! file and the 1-based line (the header is line 1).

use std::path::Path;

use super::PathLog;
use crate::error::ProcessError;

/// Reads a path log CSV.
pub fn read_path_csv(path: &Path) -> Result<PathLog, ProcessError> {
    let file = std::fs::File::open(path).map_err(|e| ProcessError::Io {
        file: path.to_path_buf(),
        what: e.to_string(),
    })?;
    read_path_from(file, path)
}

/// Reads a path log from any reader; `name` is used in errors.
pub fn read_path_from(r: impl std::io::Read, name: &Path) -> Result<PathLog, ProcessError> {
    let err = |line: usize, what: String| ProcessError::PathLog {
        file: name.to_path_buf(),
        line,
        what,
    };
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(r);
    let headers = rdr
        .headers()
        .map_err(|e| err(1, format!("cannot read the header: {e}")))?
        .clone();
    let col = |want: &str| headers.iter().position(|h| h.eq_ignore_ascii_case(want));
    let (it, ix, iy) = match (col("t_s"), col("x_mm"), col("y_mm")) {
        (Some(a), Some(b), Some(c)) => (a, b, c),
        _ => {
            return Err(err(
                1,
                format!(
                    "header must name t_s, x_mm and y_mm, found: {}",
                    headers.iter().collect::<Vec<_>>().join(",")
                ),
            ))
        }
    };
    let names = ["t_s", "x_mm", "y_mm"];
    let mut p = PathLog::default();
    for (k, rec) in rdr.records().enumerate() {
        let line = rec
            .as_ref()
            .ok()
            .and_then(|r| r.position())
            .map(|q| q.line() as usize)
            .unwrap_or(k + 2);
        let rec = rec.map_err(|e| err(line, format!("malformed CSV: {e}")))?;
        if rec.iter().all(|f| f.is_empty()) {
            continue;
        }
        let mut v = [0.0; 3];
        for (slot, (&idx, name)) in v.iter_mut().zip([it, ix, iy].iter().zip(names)) {
            let s = rec
                .get(idx)
                .ok_or_else(|| err(line, format!("missing column {name}")))?;
            let x: f64 = s
                .parse()
                .map_err(|_| err(line, format!("{name} is not a number: '{s}'")))?;
            if !x.is_finite() {
                return Err(err(line, format!("{name} is not finite: '{s}'")));
            }
            *slot = x;
        }
        if let Some(&last) = p.t_s.last() {
            if v[0] <= last {
                return Err(err(
                    line,
                    format!("t_s must increase strictly ({} after {last})", v[0]),
                ));
            }
        }
        p.t_s.push(v[0]);
        p.x_mm.push(v[1]);
        p.y_mm.push(v[2]);
    }
    if p.len() < 2 {
        return Err(err(1, "a path log needs at least two samples".into()));
    }
    Ok(p)
}

/// Writes a path log as CSV text (`t_s,x_mm,y_mm`), full precision.
pub fn path_to_csv(p: &PathLog) -> String {
    let mut s = String::with_capacity(p.len() * 32 + 16);
    s.push_str("t_s,x_mm,y_mm\n");
    for k in 0..p.len() {
        s.push_str(&format!("{},{},{}\n", p.t_s[k], p.x_mm[k], p.y_mm[k]));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(s: &str) -> Result<PathLog, ProcessError> {
        read_path_from(s.as_bytes(), Path::new("p.csv"))
    }

    #[test]
    fn reads_any_column_order_and_ignores_extras() {
        let p = read("x_mm,feed,t_s,y_mm\n1,9,0,2\n3,9,0.5,4\n").unwrap();
        assert_eq!(p.t_s, vec![0.0, 0.5]);
        assert_eq!(p.x_mm, vec![1.0, 3.0]);
        assert_eq!(p.y_mm, vec![2.0, 4.0]);
        let back = read(&path_to_csv(&p)).unwrap();
        assert_eq!(back, p);
    }

    #[test]
    fn errors_name_file_and_line() {
        let e = read("t_s,x_mm,y_mm\n0,0,0\n1,0,0\n1,2,0\n")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("p.csv: line 4:"), "{e}");
        let e = read("t_s,x_mm,y_mm\n0,0,0\n1,NaN,0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("x_mm"), "{e}");
        let e = read("t_s,x_mm,y_mm\n0,0,0\n1,abc,0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3"), "{e}");
        let e = read("time,x,y\n0,0,0\n").unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("t_s"), "{e}");
        let e = read("t_s,x_mm,y_mm\n0,0\n").unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }
}
