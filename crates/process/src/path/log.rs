//! Reading tool-path logs: CSV with a header naming at least `t_s`, `x_mm`, `y_mm` (any order;
//! extra columns are ignored), time strictly increasing, every value finite. Errors name the
//! file and the 1-based line (the header is line 1).

use std::path::Path;

use super::PathLog;
use crate::error::ProcessError;

/// Largest |x| or |y| accepted (mm): 100 m, beyond any polishing cell's workspace. A log with
/// larger coordinates has the wrong units or is corrupt; it is refused at its line, before any
/// simulation sizes a grid or a re-timed path from it.
pub const MAX_ABS_COORD_MM: f64 = 1.0e5;
/// Largest |t_s| accepted (s): about 3 years.
pub const MAX_ABS_TIME_S: f64 = 1.0e8;

/// Longest header line accepted (bytes): a header names a handful of columns.
pub const MAX_HEADER_BYTES: usize = 64 * 1024;

/// Reads a path log CSV: a regular file (a FIFO or `/dev/zero` is refused before it is opened)
/// of at most `bonnetlab_io::input::LOG_LIMIT` bytes.
pub fn read_path_csv(path: &Path) -> Result<PathLog, ProcessError> {
    let bytes =
        bonnetlab_io::input::read_bounded(path, bonnetlab_io::input::LOG_LIMIT).map_err(|e| {
            ProcessError::Io {
                file: path.to_path_buf(),
                what: format!("cannot read the path log: {e}"),
            }
        })?;
    read_path_from(&bytes[..], path)
}

/// Reads a path log from any reader; `name` is used in errors. The header line is read first,
/// with a bound ([`MAX_HEADER_BYTES`]), so an endless or binary stream is refused at once.
pub fn read_path_from(r: impl std::io::Read, name: &Path) -> Result<PathLog, ProcessError> {
    use std::io::{BufRead, Read};
    let err = |line: usize, what: String| ProcessError::PathLog {
        file: name.to_path_buf(),
        line,
        what,
    };
    let mut r = std::io::BufReader::new(r);
    let mut header = Vec::new();
    (&mut r)
        .take(MAX_HEADER_BYTES as u64 + 1)
        .read_until(b'\n', &mut header)
        .map_err(|e| err(1, format!("cannot read the header: {e}")))?;
    if header.len() > MAX_HEADER_BYTES {
        return Err(err(
            1,
            format!("the header line is longer than {MAX_HEADER_BYTES} bytes: not a path log"),
        ));
    }
    let r = std::io::Cursor::new(header).chain(r);
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(r);
    let headers = rdr
        .headers()
        .map_err(|e| err(1, format!("cannot read the header: {e}")))?
        .clone();
    let col = |want: &str| headers.iter().position(|h| h.eq_ignore_ascii_case(want));
    for want in ["t_s", "x_mm", "y_mm"] {
        if headers
            .iter()
            .filter(|h| h.eq_ignore_ascii_case(want))
            .count()
            > 1
        {
            return Err(err(
                1,
                format!("the header names {want} more than once: which column is meant?"),
            ));
        }
    }
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
    // The line of each sample, for the sampling-rate check below.
    let mut lines: Vec<usize> = Vec::new();
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
            let bound = if name == "t_s" {
                MAX_ABS_TIME_S
            } else {
                MAX_ABS_COORD_MM
            };
            if x.abs() > bound {
                let unit = if name == "t_s" { "s" } else { "mm" };
                return Err(err(
                    line,
                    format!("{name} = {x:e} is outside +-{bound:e} {unit} (wrong units?)"),
                ));
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
        lines.push(line);
    }
    if p.len() < 2 {
        return Err(err(1, "a path log needs at least two samples".into()));
    }
    check_rate(&p).map_err(|(k, what)| err(lines[k], what))?;
    Ok(p)
}

/// The slowest sampling a path log may have (shared/spec/interfaces.md: at least 5 Hz). Dwell is
/// the time between samples, so a slower log leaves the path between them unknown: a 1 Hz log of
/// the sample run moves 10 mm between samples and its simulation is meaningless.
pub const MIN_RATE_HZ: f64 = 5.0;

/// An interval longer than 1 / [`MIN_RATE_HZ`] is still read as known when the tool moves at
/// most this far in it (mm): a slow feed logged every 0.1 mm, at 4 Hz, is as good as a fast log,
/// and a pause at a point moves nothing.
pub const MAX_SLOW_STEP_MM: f64 = 0.5;

/// The share of a log's intervals that may be both slower than 1 / [`MIN_RATE_HZ`] and longer
/// than [`MAX_SLOW_STEP_MM`] (a lift, a move between segments); more, and part of the path is
/// not known.
pub const MAX_COARSE_SHARE: f64 = 0.1;

/// Checks the log's sampling: at most [`MAX_COARSE_SHARE`] of its intervals may be both slower
/// than 1 / [`MIN_RATE_HZ`] and longer than [`MAX_SLOW_STEP_MM`]. On failure, the index of the
/// first sample that ends such an interval and what is wrong.
fn check_rate(p: &PathLog) -> Result<(), (usize, String)> {
    let slow = 1.0 / MIN_RATE_HZ * (1.0 + 1e-9);
    let coarse: Vec<(usize, f64, f64)> = (1..p.len())
        .map(|i| {
            let dt = p.t_s[i] - p.t_s[i - 1];
            let step = (p.x_mm[i] - p.x_mm[i - 1]).hypot(p.y_mm[i] - p.y_mm[i - 1]);
            (i, dt, step)
        })
        .filter(|&(_, dt, step)| dt > slow && step > MAX_SLOW_STEP_MM)
        .collect();
    let intervals = (p.len() - 1) as f64;
    if (coarse.len() as f64) <= MAX_COARSE_SHARE * intervals {
        return Ok(());
    }
    let (k, dt, step) = coarse[0];
    Err((
        k,
        format!(
            "{} of {} intervals are slower than {MIN_RATE_HZ} Hz and move more than \
             {MAX_SLOW_STEP_MM} mm (this sample: {dt:.3} s and {step:.3} mm after the one \
             before): the path between samples is not known; a path log must be sampled at \
             {MIN_RATE_HZ} Hz or more (at most {:.0} % of its intervals slower and longer)",
            coarse.len(),
            p.len() - 1,
            100.0 * MAX_COARSE_SHARE
        ),
    ))
}

/// Checks that every sample lies within `x_mm` x `y_mm` (the part) widened by `margin_mm` (the
/// spot radius): a sample further out cannot touch the part, so it is an error naming the log and
/// the sample rather than a grid sized to reach it. For the simulation pipelines.
pub fn check_extent(
    p: &PathLog,
    name: &Path,
    x_mm: (f64, f64),
    y_mm: (f64, f64),
    margin_mm: f64,
) -> Result<(), ProcessError> {
    let m = margin_mm.max(0.0);
    for k in 0..p.len() {
        let (x, y) = (p.x_mm[k], p.y_mm[k]);
        if x < x_mm.0 - m || x > x_mm.1 + m || y < y_mm.0 - m || y > y_mm.1 + m {
            return Err(ProcessError::PathLog {
                file: name.to_path_buf(),
                line: k + 2,
                what: format!(
                    "sample {} at ({x:.6e}, {y:.6e}) mm is outside the part [{}, {}] x [{}, {}] mm \
                     plus the spot ({m} mm)",
                    k + 1,
                    x_mm.0,
                    x_mm.1,
                    y_mm.0,
                    y_mm.1
                ),
            });
        }
    }
    Ok(())
}

/// The extent rule of a run (`simulate` and `calibrate` apply it before sizing anything from
/// the log): every sample lies on the part `grid` plus the spot's half extent
/// (`spot_half_extent_mm`, the larger of X and Y) plus one part length of overtravel
/// (turnarounds off the part); anything further is a corrupt log, refused at its line by
/// [`check_extent`].
pub fn check_run_extent(
    p: &PathLog,
    name: &Path,
    grid: &crate::Grid,
    spot_half_extent_mm: (f64, f64),
) -> Result<(), ProcessError> {
    let (ex, ey) = spot_half_extent_mm;
    let x = (grid.x0_mm, grid.x_mm(grid.cols - 1));
    let y = (grid.y0_mm, grid.y_mm(grid.rows - 1));
    check_extent(p, name, x, y, ex.max(ey) + (x.1 - x.0).max(y.1 - y.0))
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
        let p = read("x_mm,feed,t_s,y_mm\n1,9,0,2\n3,9,0.125,4\n").unwrap();
        assert_eq!(p.t_s, vec![0.0, 0.125]);
        assert_eq!(p.x_mm, vec![1.0, 3.0]);
        assert_eq!(p.y_mm, vec![2.0, 4.0]);
        let back = read(&path_to_csv(&p)).unwrap();
        assert_eq!(back, p);
    }

    /// A log slower than 5 Hz is refused at the first sample after a long interval; a 5 Hz
    /// log, and a fast one with a pause, are read.
    #[test]
    fn a_log_slower_than_5_hz_is_refused() {
        let slow = "t_s,x_mm,y_mm\n0,0,0\n0.1,1,0\n1.1,2,0\n2.1,3,0\n3.1,4,0\n";
        let e = read(slow).unwrap_err().to_string();
        assert!(
            e.contains("line 4") && e.contains("3 of 4 intervals"),
            "{e}"
        );
        assert!(read("t_s,x_mm,y_mm\n0,0,0\n0.2,1,0\n0.4,2,0\n0.6,3,0\n").is_ok());
        let pause = "t_s,x_mm,y_mm\n0,0,0\n0.1,1,0\n5.1,1,0\n5.2,2,0\n";
        assert!(read(pause).is_ok());
        let twice = read("t_s,x_mm,y_mm,X_MM\n0,0,0,1\n0.1,1,0,2\n").unwrap_err();
        assert!(twice
            .to_string()
            .contains("line 1: the header names x_mm more than once"));
        // A fast log whose last 40 % is thinned to 1 Hz, 2 mm apart: refused.
        let mut mixed = String::from("t_s,x_mm,y_mm\n");
        for k in 0..60 {
            mixed += &format!("{},{},0\n", 0.02 * k as f64, 0.04 * k as f64);
        }
        for k in 0..40 {
            mixed += &format!("{},{},0\n", 2.0 + k as f64, 3.0 + 2.0 * k as f64);
        }
        assert!(read(&mixed).is_err());
        // A slow feed logged densely along the path: 4 Hz, 0.1 mm apart.
        let dense = "t_s,x_mm,y_mm\n0,0,0\n0.25,0.1,0\n0.5,0.2,0\n0.75,0.3,0\n";
        assert!(read(dense).is_ok());
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

    #[test]
    fn implausible_coordinates_and_long_headers_are_refused_at_their_line() {
        let e = read("t_s,x_mm,y_mm\n0,0,0\n1,1e12,0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("x_mm = 1e12"), "{e}");
        let e = read("t_s,x_mm,y_mm\n0,0,0\n1e9,1,0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("t_s"), "{e}");
        let long = format!(
            "t_s,x_mm,y_mm,{}\n0,0,0\n1,0,0\n",
            "a".repeat(MAX_HEADER_BYTES)
        );
        let e = read(&long).unwrap_err().to_string();
        assert!(
            e.contains("line 1") && e.contains("header line is longer"),
            "{e}"
        );
        let zeros = vec![0u8; 3 * MAX_HEADER_BYTES];
        let e = read_path_from(&zeros[..], Path::new("p.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1"), "{e}");
    }

    #[test]
    fn extent_check_names_the_first_sample_outside() {
        let p = read("t_s,x_mm,y_mm\n0,0,0\n0.1,50,0\n0.2,80,0\n").unwrap();
        check_extent(&p, Path::new("p.csv"), (0.0, 60.0), (0.0, 60.0), 25.0).unwrap();
        let e = check_extent(&p, Path::new("p.csv"), (0.0, 60.0), (0.0, 60.0), 10.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 4") && e.contains("sample 3"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn special_files_are_refused_without_blocking() {
        let e = read_path_csv(Path::new("/dev/zero"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("character device"), "{e}");
    }
}
