//! Small text helpers shared by the readers: Latin-1 decoding of fixed-width header strings,
//! quote-aware tokenising of Zygo ASCII header lines, and big-endian / little-endian field reads
//! that never panic.

/// Decodes bytes as Latin-1 (every byte is one char), stops at the first NUL and trims spaces.
/// MetroPro text fields are NUL- or space-padded and may hold CP1252 / Latin-1 text.
pub fn latin1_field(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let s: String = bytes[..end].iter().map(|&b| b as char).collect();
    s.trim().to_string()
}

/// Decodes a whole byte string as Latin-1.
pub fn latin1(bytes: &[u8]) -> String {
    bytes.iter().map(|&b| b as char).collect()
}

/// Splits a header line into tokens: runs of non-whitespace, or `"..."` strings (the quotes
/// removed, inner spaces kept). An unterminated quote runs to the end of the line.
pub fn tokenize_quoted(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut chars = line.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_whitespace() {
            chars.next();
        } else if c == '"' {
            chars.next();
            let mut tok = String::new();
            for ch in chars.by_ref() {
                if ch == '"' {
                    break;
                }
                tok.push(ch);
            }
            out.push(tok);
        } else {
            let mut tok = String::new();
            while let Some(&ch) = chars.peek() {
                if ch.is_whitespace() || ch == '"' {
                    break;
                }
                tok.push(ch);
                chars.next();
            }
            out.push(tok);
        }
    }
    out
}

/// Reads `N` bytes at `off`, or `None` past the end.
fn take<const N: usize>(b: &[u8], off: usize) -> Option<[u8; N]> {
    let s = b.get(off..off.checked_add(N)?)?;
    let mut a = [0u8; N];
    a.copy_from_slice(s);
    Some(a)
}

pub fn be_u16(b: &[u8], off: usize) -> Option<u16> {
    take::<2>(b, off).map(u16::from_be_bytes)
}
pub fn be_i16(b: &[u8], off: usize) -> Option<i16> {
    take::<2>(b, off).map(i16::from_be_bytes)
}
pub fn be_u32(b: &[u8], off: usize) -> Option<u32> {
    take::<4>(b, off).map(u32::from_be_bytes)
}
pub fn be_i32(b: &[u8], off: usize) -> Option<i32> {
    take::<4>(b, off).map(i32::from_be_bytes)
}
pub fn be_f32(b: &[u8], off: usize) -> Option<f32> {
    take::<4>(b, off).map(f32::from_be_bytes)
}
pub fn le_i32(b: &[u8], off: usize) -> Option<i32> {
    take::<4>(b, off).map(i32::from_le_bytes)
}

/// UTC calendar date-time of a Unix time stamp, ISO 8601 (`2018-03-30T19:06:26Z`).
pub fn unix_to_iso8601(t: i64) -> String {
    let days = t.div_euclid(86_400);
    let secs = t.rem_euclid(86_400);
    // Civil-from-days (proleptic Gregorian), after H. Hinnant's public-domain algorithm.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        secs / 3600,
        (secs / 60) % 60,
        secs % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quoted_tokens_keep_inner_spaces() {
        let t = tokenize_quoted(r#"640 480 28 0 63026 0 "10X  Mirau (VC edited)""#);
        assert_eq!(t.len(), 7);
        assert_eq!(t[6], "10X  Mirau (VC edited)");
        let t = tokenize_quoted("1 8 1 5 \"Thu Feb 08 16:18:12 2007     \"\r");
        assert_eq!(t[4], "Thu Feb 08 16:18:12 2007     ");
        assert_eq!(tokenize_quoted("\"\"").len(), 1);
    }

    #[test]
    fn latin1_stops_at_nul_and_keeps_high_bytes() {
        assert_eq!(latin1_field(b" 20X  Mirau\0\0junk"), "20X  Mirau");
        assert_eq!(latin1_field(&[0x4d, 0xe9, 0x0]), "M\u{e9}");
    }

    #[test]
    fn three_digit_exponents_parse() {
        assert_eq!("5.7e-007".parse::<f64>().unwrap(), 5.7e-7);
        assert_eq!("6.328e-007".parse::<f64>().unwrap(), 6.328e-7);
    }

    #[test]
    fn unix_time_matches_known_dates() {
        assert_eq!(unix_to_iso8601(0), "1970-01-01T00:00:00Z");
        // 2000-03-01 is day 11017 since the epoch (leap-year boundary).
        assert_eq!(
            unix_to_iso8601(11_017 * 86_400 + 3_661),
            "2000-03-01T01:01:01Z"
        );
        assert_eq!(unix_to_iso8601(951_782_400), "2000-02-29T00:00:00Z");
    }

    #[test]
    fn field_reads_never_panic() {
        assert_eq!(be_u32(&[1, 2, 3], 0), None);
        assert_eq!(be_u16(&[1, 2], usize::MAX), None);
        assert_eq!(be_i32(&[0x80, 0, 0, 0], 0), Some(i32::MIN));
    }
}
