//! MetroPro `.dat` writer: header format 1 (834 bytes), no intensity, phase as i32 BE counts.
//!
//! Scaling: S = 0.5, O = 1, W = the map's wavelength (632.8 nm when unknown), `phase_res` 1
//! (R = 32768, one count = W/65536 ~ 9.7 pm) when the heights fit in i32 counts, else 0
//! (R = 4096). Counts are computed with the f32 value of W that the reader will see, so a read
//! gives back every height within half a count. Invalid pixels hold 2147483640. `lateral_res`
//! is dx in m (0 when unknown); `cn_org` is the origin in pixels when it is a small non-negative
//! integer multiple of dx. Offsets follow spec zygo-formats.md §2.3; a test reads them back
//! byte by byte, independently of our reader.

use bonnetlab_surface::Surface;

use crate::zygo_meta::NO_DATA_MIN;

pub const HEADER_SIZE: usize = 834;
const DEFAULT_WAVELENGTH_M: f64 = 632.8e-9;

/// Why a map cannot be written as `.dat`.
pub type Unrepresentable = String;

/// Encodes a surface as a format-1 `.dat` file.
pub fn encode(s: &Surface) -> Result<Vec<u8>, Unrepresentable> {
    let (rows, cols) = s.dim();
    let (Ok(h16), Ok(w16)) = (u16::try_from(rows), u16::try_from(cols)) else {
        return Err(format!(
            "a {rows} x {cols} map is too large for .dat (at most 65535 x 65535)"
        ));
    };
    if rows == 0 || cols == 0 {
        return Err("an empty map cannot be written as .dat".into());
    }
    let pixel_m = match (s.dx_mm, s.dy_mm) {
        (Some(dx), Some(dy)) => {
            if ((dx - dy) / dx).abs() > 1e-6 {
                return Err(format!(
                    ".dat holds one pixel size; this map has dx = {dx} mm and dy = {dy} mm"
                ));
            }
            dx * 1e-3
        }
        _ => 0.0,
    };
    let wavelength_m = s
        .provenance
        .wavelength_m
        .filter(|w| w.is_finite() && *w > 1e-8 && *w < 1e-4)
        .unwrap_or(DEFAULT_WAVELENGTH_M);
    let w32 = wavelength_m as f32;
    let (s_factor, o_factor) = (0.5f32, 1.0f32);
    let max_abs = s.valid_heights().fold(0.0f64, |m, h| m.max(h.abs()));
    // Largest count magnitude we emit, below the no-data threshold.
    let limit = f64::from(NO_DATA_MIN - 8);
    let mut choice = None;
    for (phase_res, r) in [(1i16, 32768.0), (0i16, 4096.0)] {
        let nm_per_count = f64::from(w32) * f64::from(s_factor) * f64::from(o_factor) / r * 1e9;
        if max_abs / nm_per_count <= limit {
            choice = Some((phase_res, nm_per_count));
            break;
        }
    }
    let Some((phase_res, nm_per_count)) = choice else {
        return Err(format!(
            "heights up to {max_abs:.6e} nm exceed the .dat range at this wavelength"
        ));
    };

    let mut h = vec![0u8; HEADER_SIZE];
    let put = |h: &mut Vec<u8>, off: usize, b: &[u8]| h[off..off + b.len()].copy_from_slice(b);
    put(&mut h, 0, &0x881B_036Fu32.to_be_bytes());
    put(&mut h, 4, &1u16.to_be_bytes());
    put(&mut h, 6, &(HEADER_SIZE as u32).to_be_bytes());
    // swinfo_type 0 (not MetroPro), version 0.0.0, no date: we are not Zygo software.
    let org = |o_mm: f64, d_mm: Option<f64>| -> i16 {
        let Some(d) = d_mm else { return 0 };
        let p = o_mm / d;
        if (0.0..=16384.0).contains(&p) && (p - p.round()).abs() < 1e-6 {
            p.round() as i16
        } else {
            0
        }
    };
    let (ox, oy) = (org(s.origin_mm.0, s.dx_mm), org(s.origin_mm.1, s.dy_mm));
    put(&mut h, 64, &ox.to_be_bytes());
    put(&mut h, 66, &oy.to_be_bytes());
    put(&mut h, 68, &w16.to_be_bytes());
    put(&mut h, 70, &h16.to_be_bytes());
    put(&mut h, 72, &(4 * rows as u32 * cols as u32).to_be_bytes());
    put(
        &mut h,
        80,
        &latin1_fixed(s.provenance.comment.as_deref(), 82),
    );
    put(&mut h, 162, &1i16.to_be_bytes()); // source: 1 = generated
    put(&mut h, 164, &s_factor.to_be_bytes());
    put(&mut h, 168, &w32.to_be_bytes());
    put(&mut h, 176, &o_factor.to_be_bytes());
    put(&mut h, 180, &1.0f32.to_be_bytes()); // magnification
    put(&mut h, 184, &(pixel_m as f32).to_be_bytes());
    put(&mut h, 218, &phase_res.to_be_bytes());
    put(&mut h, 232, &0i16.to_be_bytes()); // sign: heights as stored
    let cam = |n: usize, o: i16| i16::try_from(n + o as usize).unwrap_or(i16::MAX);
    put(&mut h, 234, &cam(cols, ox).to_be_bytes());
    put(&mut h, 236, &cam(rows, oy).to_be_bytes());
    put(
        &mut h,
        246,
        &latin1_fixed(s.provenance.objective.as_deref(), 12),
    );

    let mut out = h;
    out.reserve(4 * rows * cols);
    for (&z, &v) in s.heights_nm().iter().zip(s.valid()) {
        let raw = if v {
            (z / nm_per_count).round() as i32
        } else {
            NO_DATA_MIN
        };
        out.extend_from_slice(&raw.to_be_bytes());
    }
    Ok(out)
}

/// A NUL-padded Latin-1 field of `len` bytes (at least one NUL; other characters -> '?').
fn latin1_fixed(s: Option<&str>, len: usize) -> Vec<u8> {
    let mut b: Vec<u8> = s
        .unwrap_or("")
        .chars()
        .map(|c| u8::try_from(u32::from(c)).unwrap_or(b'?'))
        .take(len - 1)
        .collect();
    b.resize(len, 0);
    b
}
