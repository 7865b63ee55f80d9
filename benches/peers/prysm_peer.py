"""prysm peer for `bonnetlab stats FILE --remove piston,tilt --json` on the real Zygo files.

For every file in the data directory that prysm 0.21.1 can read (MetroPro .dat via
prysm.io.read_zygo_dat, .datx via read_zygo_datx), times prysm's pipeline in-process:
read + remove piston + remove tip/tilt (prysm's Interferogram methods) + PV/RMS. The same file
is timed through our binary as a subprocess (so our figure includes process start-up; a
`bonnetlab --version` start-up figure is printed for scale). Each side is run REPEATS times,
interleaved, and the median is reported. PV/RMS of both are compared with each other and with
the golden values of shared/spec/zygo-formats.md section 7 (copied below, heights in nm).

prysm's tip/tilt removal fits only the two tilt modes after subtracting the mean; on a partial
mask that is not the joint piston+tilt least-squares fit the spec and bonnetlab use, so a joint
NumPy lstsq plane on prysm's heights is also computed (untimed) to separate reader from fit
differences.

Usage: prysm_peer.py BONNETLAB_BINARY [DATA_DIR] [--repeats N] [--criterion DIR]
Prints a Markdown table and one JSON line per file.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import prysm
from prysm.interferogram import Interferogram
from prysm.io import read_zygo_dat, read_zygo_datx

# file -> (rows, cols, valid, PV plane nm, RMS plane nm): zygo-formats.md section 7.
GOLDEN = {
    "surfalize_test_1.dat": (480, 640, 307200, 1363.405, 13.3350),
    "pyxsurf_05_C1S01.dat": (480, 640, 307200, 289.487, 81.1547),
    "pyxsurf_07_PCO1.3S04.dat": (480, 640, 307186, 307.342, 80.6452),
    "pyxsurf_20191018_01c_flat01_difffiducials.dat": (345, 346, 93751, 327.581, 54.9766),
    "pyxsurf_03_flat04_differenceFiducials_nofid_verovero.dat": (343, 342, 91315, 1238.834, 122.6128),
    "pyxsurf_01_801B.dat": (480, 640, 122975, 736.725, 227.8523),
    "prysm_valid_zygo_dat_file.dat": (432, 425, 136359, 330.700, 44.5914),
    "monolithic_zygo_test.datx": (259, 33, 7771, 457.569, 80.1964),
}


def prysm_read(path):
    return read_zygo_datx(path) if path.endswith(".datx") else read_zygo_dat(path)


def prysm_pipeline(path):
    """prysm's own steps: read, remove piston, remove tip/tilt, PV and RMS (nm)."""
    i = Interferogram.from_zygo_dat(path)
    i.remove_piston()
    i.remove_tiptilt()
    return i


def joint_plane(phase):
    """Joint least-squares plane (piston + x + y in pixel indices) over the finite pixels."""
    rows, cols = np.nonzero(np.isfinite(phase))
    z = phase[rows, cols]
    a = np.column_stack([np.ones_like(z), cols.astype(float), rows.astype(float)])
    coef, *_ = np.linalg.lstsq(a, z, rcond=None)
    r = z - a @ coef
    return float(r.max() - r.min()), float(np.sqrt(np.mean(r * r)))


def time_once(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def ours(binary, path):
    p = subprocess.run(
        [binary, "stats", path, "--remove", "piston,tilt", "--json"],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(p.stdout)


def rel(a, b):
    return abs(a - b) / abs(b) if b else float("nan")


def criterion_median_s(crit_dir, group, name):
    f = os.path.join(crit_dir, group, name, "new", "estimates.json")
    try:
        with open(f) as fh:
            return json.load(fh)["median"]["point_estimate"] * 1e-9
    except OSError:
        return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.abspath(os.path.join(here, "..", ".."))
    ap.add_argument("data", nargs="?", default=os.path.join(root, "..", "shared", "data", "real"))
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--criterion", default=os.path.join(root, "target", "criterion"))
    args = ap.parse_args()

    print(f"== prysm {prysm.__version__}, numpy {np.__version__}; machine: {os.cpu_count()} cores, "
          f"{time.strftime('%Y-%m-%dT%H:%MZ', time.gmtime())}, load {os.getloadavg()}")
    startup = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        subprocess.run([args.binary, "--version"], check=True, capture_output=True)
        startup.append(time.perf_counter() - t0)
    startup_s = statistics.median(startup)
    print(f"bonnetlab --version (process start-up only): median {startup_s * 1e3:.2f} ms")
    py_startup = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import prysm.interferogram, prysm.io"], check=True)
        py_startup.append(time.perf_counter() - t0)
    print(f"python -c 'import prysm.interferogram, prysm.io' (not in the prysm figures): "
          f"median {statistics.median(py_startup) * 1e3:.0f} ms")

    rows_out = []
    skipped = []
    for name in sorted(os.listdir(args.data)):
        path = os.path.join(args.data, name)
        if not name.endswith((".dat", ".datx")):
            if name.endswith(".asc"):
                skipped.append((name, "prysm 0.21.1 has no Zygo ASCII reader (write_zygo_ascii only)"))
            continue
        try:
            prysm_read(path)
            prysm_pipeline(path)
        except Exception as e:  # prysm's failure is the finding; report it and go on
            skipped.append((name, f"prysm raised {type(e).__name__}: {e}"))
            continue
        t_prysm, t_read, t_ours = [], [], []
        for _ in range(args.repeats):
            dt, _ = time_once(lambda: prysm_read(path))
            t_read.append(dt)
            dt, i = time_once(lambda: (lambda i: (i, i.pv, i.rms))(prysm_pipeline(path)))
            t_prysm.append(dt)
            dt, o = time_once(lambda: ours(args.binary, path))
            t_ours.append(dt)
        _, pv_p, rms_p = i
        phase = prysm_read(path)["phase"]
        pv_j, rms_j = joint_plane(phase)
        g = GOLDEN.get(name)
        r = {
            "file": name,
            "rows": int(phase.shape[0]),
            "cols": int(phase.shape[1]),
            "valid_prysm": int(np.isfinite(phase).sum()),
            "valid_ours": o["valid"],
            "prysm_read_s": statistics.median(t_read),
            "prysm_s": statistics.median(t_prysm),
            "ours_subprocess_s": statistics.median(t_ours),
            "pv_prysm_nm": float(pv_p),
            "rms_prysm_nm": float(rms_p),
            "pv_prysm_joint_nm": pv_j,
            "rms_prysm_joint_nm": rms_j,
            "pv_ours_nm": o["pv_nm"],
            "rms_ours_nm": o["rms_nm"],
            "pv_golden_nm": g[3] if g else None,
            "rms_golden_nm": g[4] if g else None,
        }
        rows_out.append(r)
        print(json.dumps(r))

    print()
    print("| file | rows x cols | prysm read+fit+PV/RMS (ms) | ours subprocess (ms) | ours / prysm "
          "| PV prysm / ours (nm) | rel. diff | RMS prysm / ours (nm) | rel. diff "
          "| prysm joint plane PV / RMS vs ours | ours vs golden PV / RMS |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows_out:
        gpv, grms = r["pv_golden_nm"], r["rms_golden_nm"]
        gold = (f"{rel(r['pv_ours_nm'], gpv):.1e} / {rel(r['rms_ours_nm'], grms):.1e}"
                if gpv is not None else "n/a")
        print(f"| {r['file']} | {r['rows']} x {r['cols']} | {r['prysm_s'] * 1e3:.2f} "
              f"| {r['ours_subprocess_s'] * 1e3:.2f} | {r['ours_subprocess_s'] / r['prysm_s']:.2f} "
              f"| {r['pv_prysm_nm']:.3f} / {r['pv_ours_nm']:.3f} "
              f"| {rel(r['pv_prysm_nm'], r['pv_ours_nm']):.1e} "
              f"| {r['rms_prysm_nm']:.4f} / {r['rms_ours_nm']:.4f} "
              f"| {rel(r['rms_prysm_nm'], r['rms_ours_nm']):.1e} "
              f"| {rel(r['pv_prysm_joint_nm'], r['pv_ours_nm']):.1e} / "
              f"{rel(r['rms_prysm_joint_nm'], r['rms_ours_nm']):.1e} | {gold} |")
    print()
    print("| file | prysm read only (ms) |")
    print("|---|---|")
    for r in rows_out:
        print(f"| {r['file']} | {r['prysm_read_s'] * 1e3:.2f} |")
    for grp, label in [("dat_640x480_real", "surfalize_test_1.dat")]:
        rd = criterion_median_s(args.criterion, grp, "read")
        rs = criterion_median_s(args.criterion, grp, "read+stats")
        if rd is not None:
            print(f"\nours in-process (criterion, benches/io.rs, {label}): read {rd * 1e3:.2f} ms"
                  + (f", read+piston/tilt+stats {rs * 1e3:.2f} ms" if rs is not None else ""))
    if skipped:
        print("\nprysm could not read / skipped:")
        for name, why in skipped:
            print(f"- {name}: {why}")
    print(f"\n== after: load {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
