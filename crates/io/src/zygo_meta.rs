//! What the MetroPro binary header and the Zygo ASCII/XYZ headers share: the fields that scale
//! raw counts to heights and the descriptive fields that become the map's provenance.
//!
//! Scaling (spec zygo-formats.md §2.5): `h_m = raw * W * S * O / R`, with `R` = 4096, 32768,
//! 131072 for `phase_res` 0, 1, 2 (the MetroPro Reference Guide table; surfalize's 1/2/3 map is
//! wrong), negated when `sign` is non-zero; raw values `>= 2147483640` mean no data.

use bonnetlab_surface::Provenance;

use crate::error::ParseError;
use crate::text::unix_to_iso8601;

/// Raw phase values at or above this are "no data" (0x7FFFFFF8; every source agrees).
pub const NO_DATA_MIN: i32 = 2_147_483_640;

/// The header fields common to the .dat, .asc and .xyz headers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ZygoMeta {
    pub swinfo_type: i32,
    pub version: (i32, i32, i32),
    pub swinfo_date: String,
    pub time_stamp: i64,
    pub comment: String,
    pub part_name: String,
    pub part_ser_num: String,
    /// S, W (m), O: the fields of the height scale.
    pub intf_scale_factor: f64,
    pub wavelength_m: f64,
    pub obliquity_factor: f64,
    /// Camera resolution in m/pixel; 0 means unknown.
    pub lateral_res_m: f64,
    pub phase_res: i32,
    pub sign: i32,
    pub sys_type: i32,
    pub serial: i64,
    pub obj_name: String,
    pub zoom_descr: String,
    pub cn_org: (i32, i32),
}

impl ZygoMeta {
    /// nm per raw count, after checking the fields that enter it.
    pub fn nm_per_count(&self) -> Result<f64, ParseError> {
        let r = match self.phase_res {
            0 => 4096.0,
            1 => 32768.0,
            2 => 131072.0,
            other => return Err(ParseError::field("phase_res", other, "is not 0, 1 or 2")),
        };
        for (name, v) in [
            ("intf_scale_factor", self.intf_scale_factor),
            ("wavelength_in", self.wavelength_m),
            ("obliquity_factor", self.obliquity_factor),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ParseError::field(name, v, "must be positive and finite"));
            }
        }
        let s = self.wavelength_m * self.intf_scale_factor * self.obliquity_factor / r * 1e9;
        Ok(if self.sign != 0 { -s } else { s })
    }

    /// Pixel size in mm, `None` when the file says 0 (unknown).
    pub fn pixel_mm(&self) -> Result<Option<f64>, ParseError> {
        let v = self.lateral_res_m;
        if v == 0.0 {
            Ok(None)
        } else if v.is_finite() && v > 0.0 {
            Ok(Some(v * 1e3))
        } else {
            Err(ParseError::field(
                "lateral_res",
                v,
                "must be 0 (unknown) or a positive pixel size in m",
            ))
        }
    }

    /// Centre of the first pixel in mm: the phase window's corner in camera pixels, times the
    /// pixel size (pixel units when that is unknown), so maps of one camera share a frame.
    pub fn origin_mm(&self, pixel_mm: Option<f64>) -> (f64, f64) {
        let p = pixel_mm.unwrap_or(1.0);
        (f64::from(self.cn_org.0) * p, f64::from(self.cn_org.1) * p)
    }

    /// Provenance for a map with this header.
    pub fn provenance(&self, format: &str) -> Provenance {
        let non_empty = |s: &str| {
            let t = s.trim();
            (!t.is_empty()).then(|| t.to_string())
        };
        let software_name = match self.swinfo_type {
            1 => "MetroPro",
            2 => "MetroBasic",
            3 => "dbug",
            // Mx exports write swinfo_type 0 (spec §2.6).
            0 => "Mx",
            _ => "unknown software",
        };
        let (a, b, c) = self.version;
        let mut software = format!("{software_name} {a}.{b}.{c}");
        if let Some(d) = non_empty(&self.swinfo_date) {
            software.push_str(&format!(" (build {d})"));
        }
        // Type 0 with no version is what non-Zygo writers (bonnetlab included) leave.
        let software = (self.swinfo_type != 0
            || self.version != (0, 0, 0)
            || !self.swinfo_date.trim().is_empty())
        .then_some(software);
        // System type names as in Gwyddion's table; real NewView files carry values beyond it.
        let sys_name = match self.sys_type {
            0 => Some("software"),
            1 => Some("Mark IVxp"),
            2 => Some("Maxim 3D"),
            3 => Some("Maxim NT"),
            4 => Some("GPI-XP"),
            5 => Some("NewView"),
            6 => Some("Maxim GP"),
            7 => Some("NewView/GP"),
            8 => Some("Mark-to-GPI"),
            _ => None,
        };
        let mut instrument = match sys_name {
            Some(n) => format!("Zygo {n} (sys_type {})", self.sys_type),
            None => format!("Zygo sys_type {}", self.sys_type),
        };
        if self.serial != 0 {
            instrument.push_str(&format!(", serial {}", self.serial));
        }
        let objective = match (non_empty(&self.obj_name), non_empty(&self.zoom_descr)) {
            (Some(o), Some(z)) => Some(format!("{o}, zoom {z}")),
            (Some(o), None) => Some(o),
            (None, Some(z)) => Some(format!("zoom {z}")),
            (None, None) => None,
        };
        let comment_parts: Vec<String> = [
            non_empty(&self.comment),
            non_empty(&self.part_name).map(|p| format!("part {p}")),
            non_empty(&self.part_ser_num).map(|p| format!("part serial {p}")),
        ]
        .into_iter()
        .flatten()
        .collect();
        Provenance {
            format: format.to_string(),
            source_path: None,
            instrument: Some(instrument),
            wavelength_m: (self.wavelength_m > 0.0).then_some(self.wavelength_m),
            objective,
            date: (self.time_stamp > 0).then(|| unix_to_iso8601(self.time_stamp)),
            comment: (!comment_parts.is_empty()).then(|| comment_parts.join("; ")),
            software,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> ZygoMeta {
        ZygoMeta {
            intf_scale_factor: 0.5,
            wavelength_m: 632.8e-9,
            obliquity_factor: 1.0,
            phase_res: 1,
            ..ZygoMeta::default()
        }
    }

    #[test]
    fn one_count_is_the_documented_step() {
        // spec §2.5: one count at S = 0.5, O = 1, R = 32768 is 9.66 pm at 632.8 nm.
        let s = meta().nm_per_count().unwrap();
        assert!((s - 632.8 * 0.5 / 32768.0).abs() < 1e-15);
        assert!((s * 1e3 - 9.66).abs() < 0.005);
        let mut m = meta();
        m.sign = 1;
        assert_eq!(m.nm_per_count().unwrap(), -s);
        m.phase_res = 2;
        assert!((m.nm_per_count().unwrap() + s / 4.0).abs() < 1e-15);
    }

    #[test]
    fn unknown_phase_res_names_the_field() {
        let mut m = meta();
        m.phase_res = 7;
        let e = m.nm_per_count().unwrap_err().to_string();
        assert_eq!(e, "header field phase_res = 7 is not 0, 1 or 2");
    }
}
