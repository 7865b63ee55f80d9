//! Rendering of height statistics (`pipeline::stats`): the `stats` table and its band lines
//! (also in the `psd` summary).

use bonnetlab_spectrum::ArealBands;
use bonnetlab_surface::Term;

use crate::pipeline::stats::StatsReport;

/// The `stats` table of a map.
pub fn table(r: &StatsReport) -> String {
    // The pixel size to the precision files store it (f32: 7 significant digits), as `psd`.
    let mm = |v: Option<f64>| {
        v.map_or("unknown".to_string(), |v| {
            format!("{} mm", crate::report::format::f32_value(v))
        })
    };
    let removed: Vec<&str> = r.removed.iter().map(Term::name).collect();
    let removed = if removed.is_empty() {
        "none".to_string()
    } else {
        removed.join(", ")
    };
    let mut t = String::new();
    t += &format!("file      {}\n", r.file);
    if let Some(m) = &r.minus {
        t += &format!("minus     {m} (pixel by pixel, on the pixels valid in both)\n");
    }
    t += &format!("format    {}\n", r.format);
    t += &format!(
        "grid      {} rows x {} cols, dx {}, dy {}\n",
        r.rows,
        r.cols,
        mm(r.dx_mm),
        mm(r.dy_mm)
    );
    t += &format!("valid     {} pixels\n", r.valid);
    t += &format!("removed   {removed}\n");
    t += &format!("PV (Sz)   {:>12.4} nm\n", r.heights.pv_nm);
    t += &format!("RMS (Sq)  {:>12.4} nm\n", r.heights.rms_nm);
    t += &format!("Sa        {:>12.4} nm\n", r.heights.sa_nm);
    t += &format!("Sp        {:>12.4} nm\n", r.heights.sp_nm);
    t += &format!("Sv        {:>12.4} nm\n", r.heights.sv_nm);
    match (r.heights.ssk, r.heights.sku) {
        (Some(ssk), Some(sku)) => {
            t += &format!("Ssk       {ssk:>12.4}\n");
            t += &format!("Sku       {sku:>12.4}   (not minus 3)\n");
        }
        _ => t += "Ssk, Sku  undefined (a flat map: RMS 0)\n",
    }
    if let (Some(p), Some(set)) = (r.pvr_nm, r.pvr_set) {
        t += &format!("PVr       {p:>12.4} nm   ({set})\n");
    }
    if let Some(b) = &r.bands {
        t += &bands_table(b);
    }
    t
}

/// The band lines of the table: edges, each band's RMS or why it is absent, and the method.
pub fn bands_table(b: &ArealBands) -> String {
    let [f1, f2] = b.edges_per_mm;
    let sig = bonnetlab_spectrum::fmt_sig;
    let mut t = format!(
        "bands     edges {} and {} 1/mm (periods {} mm and {} mm)\n",
        sig(f1),
        sig(f2),
        if f1 > 0.0 {
            sig(1.0 / f1)
        } else {
            "inf".into()
        },
        if f2 > 0.0 {
            sig(1.0 / f2)
        } else {
            "inf".into()
        }
    );
    for (name, v, why) in b.bands() {
        let label = match name {
            "figure" => format!("  figure  (f < {} 1/mm)", sig(f1)),
            "msf" => format!("  MSF     ({} to {} 1/mm)", sig(f1), sig(f2)),
            _ => format!("  fine    (f > {} 1/mm)", sig(f2)),
        };
        match (v, why) {
            (Some(v), _) => t += &format!("{label:<34} {v:>12.4} nm\n"),
            (None, Some(why)) => t += &format!("{label:<34} absent: {why}\n"),
            (None, None) => t += &format!("{label:<34} absent\n"),
        }
    }
    t += &format!(
        "  total (Sq, quadrature sum)       {:>12.4} nm\n  method: {}\n",
        b.total_rms_nm, b.method
    );
    t
}
