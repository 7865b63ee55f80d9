//! The mutations of the reader fuzzer: bit flips, interesting bytes and integers, truncation,
//! chunk edits, MetroPro header-field overwrites, numeric-token replacement and line edits for
//! the text formats. Every choice comes from the caller's seeded generator.

use bonnetlab_io::input::TEXT_LIMIT;
use bonnetlab_surface::rng::Rng;

use super::Reader;

const INTERESTING_U32: [u32; 14] = [
    0,
    1,
    2,
    3,
    4,
    0x7F,
    0x80,
    0xFF,
    0x7FFF,
    0x8000,
    0xFFFF,
    60000,
    0x7FFF_FFFF,
    0xFFFF_FFFF,
];
const TOKENS: [&str; 16] = [
    "0",
    "-1",
    "1",
    "99999999999",
    "1e308",
    "-1e308",
    "nan",
    "NaN",
    "inf",
    "",
    "60000",
    "2147483640",
    "-0",
    "1.5",
    "0x10",
    "\"",
];
/// MetroPro header field offsets (spec/zygo-formats.md section 2.3).
const DAT_FIELDS: [usize; 24] = [
    4, 6, 48, 50, 52, 54, 56, 58, 60, 62, 64, 66, 68, 70, 72, 74, 164, 168, 176, 184, 218, 220,
    222, 224,
];

pub(super) fn mutate(r: Reader, data: &mut Vec<u8>, rng: &mut Rng) {
    let n_mut = 1 + rng.below(4);
    for _ in 0..n_mut {
        let len = data.len();
        let pos = |rng: &mut Rng, len: usize| {
            if len == 0 {
                0
            } else if rng.uniform() < 0.5 {
                rng.below(len.min(4096))
            } else {
                rng.below(len)
            }
        };
        match rng.below(10) {
            0 if len > 0 => {
                let p = pos(rng, len);
                data[p] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let p = pos(rng, len);
                data[p] = [0u8, 0xFF, 0x7F, 0x80, b'#', b'\n', b',', b'-'][rng.below(8)];
            }
            2 => data.truncate(rng.below(len + 1)),
            3 if len > 1 => {
                let a = pos(rng, len);
                let n = 1 + rng.below(64.min(len - a).max(1));
                data.drain(a..(a + n).min(len));
            }
            4 => {
                let a = rng.below(len + 1);
                let n = 1 + rng.below(64);
                let ins: Vec<u8> = (0..n).map(|_| rng.below(256) as u8).collect();
                data.splice(a..a, ins);
            }
            5 if len > 1 => {
                let a = rng.below(len);
                let n = 1 + rng.below(256.min(len - a));
                let chunk = data[a..a + n].to_vec();
                let b = rng.below(len + 1);
                data.splice(b..b, chunk);
            }
            6 | 7 if !r.is_text() && len >= 4 => {
                // Header-field overwrite: a MetroPro field or any 2-aligned offset.
                let off = if matches!(r, Reader::Dat | Reader::Detect) && rng.uniform() < 0.7 {
                    DAT_FIELDS[rng.below(DAT_FIELDS.len())]
                } else {
                    pos(rng, len) & !1
                };
                let v = if rng.uniform() < 0.8 {
                    INTERESTING_U32[rng.below(INTERESTING_U32.len())]
                } else {
                    rng.next_u64() as u32
                };
                let width = if rng.uniform() < 0.5 { 2 } else { 4 };
                let bytes = v.to_be_bytes();
                for k in 0..width {
                    if let Some(b) = data.get_mut(off + k) {
                        *b = bytes[4 - width + k];
                    }
                }
            }
            6 | 7 => {
                // Replace a numeric token with an interesting one.
                let starts: Vec<usize> = (0..len)
                    .filter(|&i| {
                        data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_digit())
                    })
                    .collect();
                if !starts.is_empty() {
                    let a = starts[rng.below(starts.len())];
                    let mut b = a;
                    while b < len
                        && (data[b].is_ascii_digit() || data[b] == b'.' || data[b] == b'e')
                    {
                        b += 1;
                    }
                    let tok = TOKENS[rng.below(TOKENS.len())].as_bytes().to_vec();
                    data.splice(a..b, tok);
                }
            }
            8 => {
                // Line edits: delete, duplicate or swap lines.
                let mut lines: Vec<Vec<u8>> =
                    data.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect();
                let nl = lines.len();
                let i = rng.below(nl);
                match rng.below(3) {
                    0 => {
                        lines.remove(i);
                    }
                    1 => {
                        let l = lines[i].clone();
                        lines.insert(i, l);
                    }
                    _ => lines.swap(i, rng.below(nl)),
                }
                *data = lines.join(&b'\n');
            }
            _ => {
                let n = 1 + rng.below(128);
                data.extend((0..n).map(|_| rng.below(256) as u8));
            }
        }
    }
}

/// Extreme numbers for the structured fuzzers: huge, tiny, subnormal, signed zero, integers past
/// u64 / u32, the non-finite spellings TOML and CSV accept, and large-but-plausible sizes (a
/// tool or path of metres, which pass "finite and positive" checks but may size big grids).
const EXTREME: [&str; 31] = [
    "1e300",
    "-1e300",
    "1e-300",
    "-1e-300",
    "1e308",
    "-1e308",
    "1.7976931348623157e308",
    "5e-324",
    "0",
    "-0.0",
    "-1",
    "1e15",
    "1e12",
    "-1e12",
    "1e7",
    "18446744073709551615",
    "4294967296",
    "9223372036854775807",
    "nan",
    "inf",
    "-inf",
    "0.5",
    "1000",
    "2500",
    "1e4",
    "65536",
    "1e5",
    "99999",
    "-1e-9",
    "1e-12",
    "340282366920938463463374607431768211456",
];

fn extreme(rng: &mut Rng) -> &'static str {
    EXTREME[rng.below(EXTREME.len())]
}

/// Replaces 1 to 4 numeric tokens of a text (TOML, CSV) by extreme values, keeping the rest of
/// its structure, so the input reaches validation rather than failing to parse.
pub fn extreme_numbers(data: &mut Vec<u8>, rng: &mut Rng) {
    for _ in 0..1 + rng.below(4) {
        let len = data.len();
        let starts: Vec<usize> = (0..len)
            .filter(|&i| {
                (data[i].is_ascii_digit() || data[i] == b'-')
                    && (i == 0 || !(data[i - 1].is_ascii_alphanumeric() || data[i - 1] == b'.'))
            })
            .collect();
        if starts.is_empty() {
            return;
        }
        let a = starts[rng.below(starts.len())];
        let mut b = a + 1;
        while b < len
            && (data[b].is_ascii_digit() || matches!(data[b], b'.' | b'e' | b'E' | b'-' | b'+'))
        {
            b += 1;
        }
        data.splice(a..b, extreme(rng).bytes());
    }
}

/// A path log of 2 to 120 rows (or, one in 20 000, 1e5 to 1e6 rows): ordinary raster-like samples, some coordinates and time steps
/// replaced by extreme values (so the readers' bounds and the re-timing's size check are hit).
pub fn extreme_path_log(rng: &mut Rng) -> Vec<u8> {
    // One input in 20 000 is a very long log (up to a million rows).
    let n = if rng.below(20_000) == 0 {
        100_000 + rng.below(900_000)
    } else {
        2 + rng.below(119)
    };
    let p_extreme = [0.0, 0.01, 0.1, 0.5][rng.below(4)];
    let dt = ["0.2", "1e7", "1e-9", "1000", "3e6"][rng.below(5)];
    let dt: f64 = dt.parse().unwrap_or(0.2);
    let mut s = String::from("t_s,x_mm,y_mm\n");
    let mut t = 0.0f64;
    for k in 0..n {
        let line = k / 20;
        let x = if line % 2 == 0 {
            (k % 20) as f64 * 5.0
        } else {
            (19 - k % 20) as f64 * 5.0
        };
        let y = line as f64 * 2.0;
        let field = |v: f64, rng: &mut Rng| {
            if rng.uniform() < p_extreme {
                extreme(rng).to_string()
            } else {
                format!("{v}")
            }
        };
        let ts = field(t, rng);
        let xs = field(x, rng);
        let ys = field(y, rng);
        s.push_str(&format!("{ts},{xs},{ys}\n"));
        t += dt;
    }
    s.into_bytes()
}

/// Values of other types, to put where a number or a string is expected.
const SWAPPED: [&str; 12] = [
    "\"3\"",
    "true",
    "[1, 2]",
    "{ a = 1 }",
    "1979-05-27",
    "\"\"",
    "3",
    "[]",
    "\"original\"",
    "\"nan\"",
    "[[1], [2]]",
    "-0",
];

/// Structural edits of a TOML text (recipe, dwell case, spot manifest): a missing key (line
/// deleted), a duplicated key or table, a value of another type, a very long string, a huge
/// number of `[[spot]]` tables or of array elements, an empty value. Applied 1 to 3 times.
pub fn structural_toml(data: &mut Vec<u8>, rng: &mut Rng) {
    for _ in 0..1 + rng.below(3) {
        let text = String::from_utf8_lossy(data).into_owned();
        let mut lines: Vec<String> = text.split('\n').map(str::to_string).collect();
        let keyed: Vec<usize> = (0..lines.len())
            .filter(|&i| lines[i].contains('=') && !lines[i].trim_start().starts_with('#'))
            .collect();
        let tables: Vec<usize> = (0..lines.len())
            .filter(|&i| lines[i].trim_start().starts_with('['))
            .collect();
        if keyed.is_empty() {
            return;
        }
        let k = keyed[rng.below(keyed.len())];
        match rng.below(8) {
            // A missing key.
            0 => {
                lines.remove(k);
            }
            // A duplicated key.
            1 => {
                let l = lines[k].clone();
                lines.insert(k + 1, l);
            }
            // A value of another type (whole value, or one entry of an inline table).
            2 | 3 => {
                let l = lines[k].clone();
                let eqs: Vec<usize> = l.match_indices('=').map(|(i, _)| i).collect();
                let e = eqs[rng.below(eqs.len())];
                let end = l[e + 1..]
                    .find([',', '}'])
                    .filter(|_| eqs.len() > 1)
                    .map_or(l.len(), |j| e + 1 + j);
                let v = SWAPPED[rng.below(SWAPPED.len())];
                lines[k] = format!("{} {v}{}", &l[..=e], &l[end..]);
            }
            // A very long string value, or a very long key (a million characters in 1 of 100).
            4 => {
                let n = if rng.below(100) == 0 {
                    1_000_000
                } else {
                    10usize.pow(1 + rng.below(4) as u32)
                };
                let l = lines[k].clone();
                let e = l.find('=').unwrap_or(0);
                lines[k] = if rng.below(4) == 0 {
                    format!("{} {}", "k".repeat(n), &l[e..])
                } else {
                    format!("{} \"{}\"", &l[..=e], "x".repeat(n))
                };
            }
            // A huge count: repeated [[spot]] tables, or an array of many numbers (100 000
            // in 1 of 1000; never past the 16 MiB the CLI reads of a text file).
            5 => {
                let n = if rng.below(1000) == 0 {
                    100_000
                } else {
                    [10, 1000][rng.below(2)]
                };
                if let Some(start) = text.rfind("[[spot]]") {
                    let block = text[start..].to_string();
                    let room = (TEXT_LIMIT as usize).saturating_sub(text.len()) / (block.len() + 1);
                    let mut t = text.clone();
                    for _ in 0..n.min(room) {
                        t.push('\n');
                        t.push_str(&block);
                    }
                    *data = t.into_bytes();
                    continue;
                }
                let l = lines[k].clone();
                let e = l.find('=').unwrap_or(0);
                let arr: Vec<String> = (0..n).map(|i| format!("{}", i % 97)).collect();
                lines[k] = format!("{} [{}]", &l[..=e], arr.join(", "));
            }
            // A duplicated table header.
            6 if !tables.is_empty() => {
                let t = tables[rng.below(tables.len())];
                let l = lines[t].clone();
                lines.push(l);
            }
            // An empty value.
            _ => {
                let l = lines[k].clone();
                let e = l.find('=').unwrap_or(0);
                lines[k] = l[..=e].to_string();
            }
        }
        *data = lines.join("\n").into_bytes();
    }
}

/// Structural edits of a CSV text (path log, CSV spot manifest): a missing column (header name
/// changed), a duplicated column name, swapped column names, a field of another type, a very
/// long field (a huge integer or text), a huge number of rows, no data rows. Applied 1 to 3
/// times.
pub fn structural_csv(data: &mut Vec<u8>, rng: &mut Rng) {
    for _ in 0..1 + rng.below(3) {
        let text = String::from_utf8_lossy(data).into_owned();
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        if lines.len() < 2 {
            return;
        }
        let mut head: Vec<String> = lines[0].split(',').map(str::to_string).collect();
        let nc = head.len();
        let row = 1 + rng.below(lines.len() - 1);
        let mut fields: Vec<String> = lines[row].split(',').map(str::to_string).collect();
        let c = rng.below(fields.len().max(1));
        match rng.below(8) {
            0 => head[rng.below(nc)] = "renamed".into(),
            1 => {
                let h = head[rng.below(nc)].clone();
                head[rng.below(nc)] = h;
            }
            2 => head.swap(rng.below(nc), rng.below(nc)),
            3 => {
                fields[c] = ["abc", "\"\"", "true", "0x10", "1;5", "1.2.3", "--1", "1e"]
                    [rng.below(8)]
                .into()
            }
            4 => {
                let n = if rng.below(100) == 0 {
                    1_000_000
                } else {
                    10usize.pow(1 + rng.below(4) as u32)
                };
                fields[c] = if rng.below(2) == 0 {
                    "9".repeat(n)
                } else {
                    "z".repeat(n)
                };
            }
            5 => {
                let n = if rng.below(1000) == 0 {
                    100_000
                } else {
                    [10, 1000][rng.below(2)]
                };
                let l = lines[lines.len() - 1].clone();
                for _ in 0..n {
                    lines.push(l.clone());
                }
            }
            6 => lines.truncate(1),
            _ => fields.push("extra".into()),
        }
        if row < lines.len() {
            lines[row] = fields.join(",");
        }
        lines[0] = head.join(",");
        let mut t = lines.join("\n");
        t.push('\n');
        *data = t.into_bytes();
    }
}
