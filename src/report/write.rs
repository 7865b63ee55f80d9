//! JSON and CSV output files, written whole or not at all through `bonnetlab_io::atomic`
//! (temporary file in the same directory, then rename), so a pipeline never reads half a report.
//! A report of several files in one `--out` directory goes through [`Set`]: every file is staged
//! first, under the directory's lock, and published only when all are written, so a failure
//! part-way leaves the directory as it was and two runs never mix their files.
//!
//! JSON is pretty-printed with a trailing newline; CSV has a header row and one row per
//! sample, numbers in Rust's shortest round-trip form (so files are byte-stable across runs).

use std::path::Path;

use serde::Serialize;

/// A write failure naming the file.
#[derive(Debug, thiserror::Error)]
#[error("{file}: cannot write: {what}")]
pub struct WriteError {
    pub file: String,
    pub what: String,
}

fn werr(path: &Path, e: impl std::fmt::Display) -> WriteError {
    WriteError {
        file: path.display().to_string(),
        what: without_os_error(&e.to_string().replace('\n', " ")),
    }
}

/// An error text without Rust's trailing " (os error N)".
fn without_os_error(s: &str) -> String {
    match s.find(" (os error ") {
        Some(i) if s.ends_with(')') => s[..i].to_string(),
        _ => s.to_string(),
    }
}

/// Encodes a value as pretty JSON with a trailing newline.
fn json_text<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<String, WriteError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| werr(path, e))?;
    text.push('\n');
    Ok(text)
}

/// Encodes columns as CSV (see [`csv_columns`]).
fn csv_text(path: &Path, header: &[&str], columns: &[&[f64]]) -> Result<Vec<u8>, WriteError> {
    let rows = columns.iter().map(|c| c.len()).max().unwrap_or(0);
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(|e| werr(path, e))?;
    for i in 0..rows {
        let rec: Vec<String> = columns
            .iter()
            .map(|c| c.get(i).map(|v| format!("{v}")).unwrap_or_default())
            .collect();
        w.write_record(&rec).map_err(|e| werr(path, e))?;
    }
    w.into_inner().map_err(|e| werr(path, e))
}

/// A set of files published together into one directory (`bonnetlab_io::atomic::OutputSet`):
/// nothing in the directory changes until [`Set::commit`]; dropping the set uncommitted leaves
/// the directory as it was.
pub struct Set {
    inner: bonnetlab_io::atomic::OutputSet,
}

impl Set {
    /// Creates `dir` if needed and takes its lock (a second run writing there is refused).
    /// `kind` names the command's set: on commit, the files the last set of that kind
    /// published in `dir` and this one does not write are removed while unchanged
    /// (`OutputSet::record_as`), so a run never leaves a former run's file beside its own.
    pub fn begin(dir: &Path, kind: &str) -> Result<Set, WriteError> {
        let mut inner = bonnetlab_io::atomic::OutputSet::begin(dir).map_err(|e| werr(dir, e))?;
        inner.record_as(kind).map_err(|e| werr(dir, e))?;
        Ok(Set { inner })
    }

    /// The final path of `name` in the directory.
    pub fn path(&self, name: &str) -> std::path::PathBuf {
        self.inner.dir().join(name)
    }

    /// Stages bytes as `name`.
    pub fn bytes(&mut self, name: &str, data: &[u8]) -> Result<(), WriteError> {
        let p = self.path(name);
        self.inner.write(name, data).map_err(|e| werr(&p, e))
    }

    /// Stages a value as pretty JSON.
    pub fn json<T: Serialize + ?Sized>(&mut self, name: &str, value: &T) -> Result<(), WriteError> {
        let text = json_text(&self.path(name), value)?;
        self.bytes(name, text.as_bytes())
    }

    /// Stages columns as CSV.
    pub fn csv_columns(
        &mut self,
        name: &str,
        header: &[&str],
        columns: &[&[f64]],
    ) -> Result<(), WriteError> {
        let data = csv_text(&self.path(name), header, columns)?;
        self.bytes(name, &data)
    }

    /// Stages a height map in `fmt` (MetroPro `.dat`, CSV or EXR).
    pub fn surface(
        &mut self,
        name: &str,
        s: &bonnetlab_surface::Surface,
        fmt: bonnetlab_io::MapFormat,
    ) -> Result<(), WriteError> {
        let data = bonnetlab_io::encode_surface(s, fmt).map_err(|e| werr(&self.path(name), e))?;
        self.bytes(name, &data)
    }

    /// Where the staged files will be published.
    pub fn destinations(&self) -> impl Iterator<Item = &Path> {
        self.inner.destinations()
    }

    /// Publishes every staged file.
    pub fn commit(self) -> Result<(), WriteError> {
        let dir = self.inner.dir().to_path_buf();
        self.inner.commit().map_err(|e| werr(&dir, e))
    }
}

/// Writes bytes atomically.
pub fn bytes(path: &Path, data: &[u8]) -> Result<(), WriteError> {
    bonnetlab_io::atomic::write_atomic(path, data).map_err(|e| werr(path, e))
}

/// Writes a value as pretty JSON, atomically.
pub fn json<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), WriteError> {
    let text = json_text(path, value)?;
    bytes(path, text.as_bytes())
}

/// Writes columns of equal length as CSV (shorter columns leave empty cells), atomically.
pub fn csv_columns(path: &Path, header: &[&str], columns: &[&[f64]]) -> Result<(), WriteError> {
    let data = csv_text(path, header, columns)?;
    bytes(path, &data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_and_csv_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        json(&p, &serde_json::json!({"x": 1.5, "y": [1, 2]})).unwrap();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert_eq!(v["x"], 1.5);
        let c = dir.path().join("c.csv");
        csv_columns(&c, &["f", "p"], &[&[0.0, 0.1, 0.2], &[1.0, 2.0]]).unwrap();
        assert_eq!(
            std::fs::read_to_string(&c).unwrap(),
            "f,p\n0,1\n0.1,2\n0.2,\n"
        );
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
    }

    #[test]
    fn unwritable_target_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("missing_dir").join("x.json");
        let e = json(&p, &1).unwrap_err();
        assert!(e.to_string().contains("x.json"), "{e}");
        assert!(!p.exists());
    }
}
