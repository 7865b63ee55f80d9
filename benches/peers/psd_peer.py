"""SurfaceTopography peer for `bonnetlab psd` (1-D PSD along X and the 2-D PSD's radial
average) on the real Zygo files, plus the effect of the 1-D segment rule of issue #19.

For every map with a pixel size in the given directories:
  * bonnetlab: `psd FILE --json --radial --window hann` (every segment used, each from its
    own first unbiased bin), the same with `--min-segment-fraction 0.5 --min-segment-px 16`
    (the segment choice before issue #19), and `--radial --window none` for the 2-D check;
  * SurfaceTopography (ContactEngineering) 1.x: read_topography (its own readers), plane
    detrend (`detrend('height')`), `power_spectrum_from_profile(window='hann')` (raw bins) and
    the 2-D map of `power_spectrum_from_area(window='None', return_map=True)` (the string
    'None': its window=None means a radial Hann on non-periodic maps), averaged over
    bonnetlab's radial bins (width max(dfx, dfy), centred on b dfr) so the bins are identical.
SurfaceTopography refuses maps with missing data; for those its
`interpolate_undefined_data()` (harmonic fill) is used first and the row says so.

Conventions (shared/spec/metrology.md): SurfaceTopography's C1D(q) [m^3], q = 2 pi f [1/m],
has mean square (1/pi) sum_{q >= 0} C1D dq, so our one-sided P1(f) [nm^2 mm] = 2 C1D * 1e21;
its C2D(q) [m^4] equals our two-sided P2 [nm^2 mm^2] times 1e-24.

Usage: psd_peer.py BONNETLAB_BINARY DATA_DIR_OR_FILE [...]
Prints a Markdown table and one JSON line per file.
"""

import json
import math
import os
import subprocess
import sys

import numpy as np
from SurfaceTopography import Topography, read_topography

UNIT_M = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9}


def ours(binary, path, *extra):
    out = subprocess.run(
        [binary, "psd", path, "--json", "--remove", "piston,tilt", *extra],
        capture_output=True,
        text=True,
    )
    if out.returncode != 0:
        return None, out.stderr.strip()
    return json.loads(out.stdout), None


def psd_sum(axis):
    """Mean square over the unbiased bins, nm^2."""
    b = axis["biased_bins"]
    return sum(axis["psd_nm2_mm"][b:]) * axis["df_per_mm"]


def compare_1d(ax, q, c, scale_len):
    """Ratios ours / SurfaceTopography at our unbiased bins (same grid: f_k = k / L)."""
    f_st = q / (2 * math.pi) * scale_len  # 1/mm
    p_st = 2.0 * c
    ratios = []
    for k in range(ax["biased_bins"], len(ax["freq_per_mm"]) - 1):
        f = ax["freq_per_mm"][k]
        j = int(round(f / ax["df_per_mm"]))
        if j >= len(f_st) or abs(f_st[j] - f) > 1e-6 * f:
            return None
        if p_st[j] > 0:
            ratios.append(ax["psd_nm2_mm"][k] / p_st[j])
    return np.array(ratios)


def compare_radial(rad, cmap, dx_mm, dy_mm, nx, ny, to_nm2mm2):
    fx = np.fft.fftfreq(nx, d=dx_mm)
    fy = np.fft.fftfreq(ny, d=dy_mm)
    fr = np.sqrt(fx[:, None] ** 2 + fy[None, :] ** 2)
    dfr = rad["dfr_per_mm"]
    b = np.floor(fr / dfr + 0.5).astype(int)
    nb = len(rad["freq_per_mm"])
    b = np.minimum(b, nb - 1)
    s = np.bincount(b.ravel(), weights=np.asarray(cmap).ravel() * to_nm2mm2, minlength=nb)
    n = np.bincount(b.ravel(), minlength=nb)
    ratios = []
    for k in range(1, nb):
        a = rad["average_nm2_mm2"][k]
        if a is not None and n[k] > 0 and s[k] > 0:
            ratios.append(a / (s[k] / n[k]))
    return np.array(ratios)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    binary = sys.argv[1]
    files = []
    for d in sys.argv[2:]:
        if os.path.isfile(d):
            files.append(d)
            continue
        for name in sorted(os.listdir(d)):
            if name.rsplit(".", 1)[-1] in ("dat", "asc", "datx", "xyz"):
                files.append(os.path.join(d, name))
    print(
        "| file | grid | valid | ST fill | X segments new / old | X PSD sum new / old | "
        "1-D X ours/ST median [min, max] | radial (no window) ours/ST median [min, max] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for path in files:
        new, err = ours(binary, path, "--radial", "--window", "hann")
        if new is None:
            print(f"| {os.path.basename(path)} | skipped: bonnetlab: {err.splitlines()[0][-90:]} |||||||")
            continue
        old, _ = ours(
            binary, path, "--window", "hann", "--min-segment-fraction", "0.5",
            "--min-segment-px", "16",
        )
        none, _ = ours(binary, path, "--radial", "--window", "none", "--axis", "x")
        try:
            t = read_topography(path)
        except Exception as e:  # a reader SurfaceTopography lacks or a file it cannot size
            why = str(e).strip().splitlines()[0][:80]
            print(f"| {os.path.basename(path)} | skipped: SurfaceTopography cannot read it ({why}) |||||||")
            continue
        unit = UNIT_M.get(str(t.unit), None)
        if unit is None:
            print(f"| {os.path.basename(path)} | skipped: SurfaceTopography unit {t.unit} |||||||")
            continue
        # SurfaceTopography's heights on bonnetlab's pixel size (the readers disagree on the
        # lateral calibration of some MetroPro files; the PSD normalisation is what is compared
        # here), in mm for both heights and lengths.
        h = np.ma.masked_invalid(t.heights()) * (unit / 1e-3)
        nx, ny = t.nb_grid_pts
        if (ny, nx) != (new["rows"], new["cols"]):
            print(f"| {os.path.basename(path)} | skipped: grid {nx}x{ny} vs ours |||||||")
            continue
        dx_mm, dy_mm = new["dx_mm"], new["dy_mm"]
        t = Topography(h, (nx * dx_mm, ny * dy_mm), unit="mm")
        fill = "none"
        if t.has_undefined_data:
            t = t.interpolate_undefined_data()
            fill = "harmonic"
        t = t.detrend("height")
        q, c = t.power_spectrum_from_profile(window="hann", resampling_method=None, reliable=False)
        # q in rad/mm, C1D in mm^3 -> nm^2 mm: x 1e12
        r1 = compare_1d(new["x"], q, c * 1e12, 1.0)
        _, _, cmap = t.power_spectrum_from_area(
            window="None", nb_points_per_decade=10, reliable=False, return_map=True
        )
        r2 = compare_radial(none["radial"], cmap, dx_mm, dy_mm, nx, ny, 1e12)

        def fmt(r):
            if r is None or len(r) == 0:
                return "n/a (grids differ)"
            return f"{np.median(r):.4f} [{r.min():.3f}, {r.max():.3f}]"

        sums = (psd_sum(new["x"]), psd_sum(old["x"]))
        print(
            f"| {os.path.basename(path)} | {new['rows']}x{new['cols']} | "
            f"{'all' if fill == 'none' else 'masked'} | {fill} | "
            f"{new['x']['n_segments']} / {old['x']['n_segments']} | "
            f"{sums[0]:.4g} / {sums[1]:.4g} nm^2 | {fmt(r1)} | {fmt(r2)} |"
        )
        row = {
            "file": os.path.basename(path),
            "st_fill": fill,
            "x_segments": [new["x"]["n_segments"], old["x"]["n_segments"]],
            "y_segments": [new["y"]["n_segments"], old["y"]["n_segments"]],
            "x_sum_nm2": sums,
            "y_sum_nm2": (psd_sum(new["y"]), psd_sum(old["y"])),
            "x_first_unbiased_bin": [new["x"]["biased_bins"], old["x"]["biased_bins"]],
            "ratio_1d_median": None if r1 is None or len(r1) == 0 else float(np.median(r1)),
            "ratio_radial_median": None if len(r2) == 0 else float(np.median(r2)),
        }
        print("<!-- " + json.dumps(row) + " -->")


if __name__ == "__main__":
    main()
