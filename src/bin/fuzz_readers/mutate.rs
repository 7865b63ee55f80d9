//! The mutations of the reader fuzzer: bit flips, interesting bytes and integers, truncation,
//! chunk edits, MetroPro header-field overwrites, numeric-token replacement and line edits for
//! the text formats. Every choice comes from the caller's seeded generator.

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
/// u64 / u32, and the non-finite spellings TOML and CSV accept.
const EXTREME: [&str; 22] = [
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

/// A path log of 2 to 400 rows: ordinary raster-like samples, some coordinates and time steps
/// replaced by extreme values (so the readers' bounds and the re-timing's size check are hit).
pub fn extreme_path_log(rng: &mut Rng) -> Vec<u8> {
    let n = 2 + rng.below(399);
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
