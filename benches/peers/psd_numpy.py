"""NumPy / SciPy peer of benches/spectrum.rs: the same work, the same conventions.

Workloads on an N x N fully valid map (dx = dy = 0.1 mm, 10 nm ripple with a 3 mm pitch
along Y, a tilt, 2 nm white noise):
  psd_xy_ripple/N  piston + tilt removed jointly (least squares on normalised coordinates,
                   normal equations from separable sums: the fastest form for a full grid),
                   1-D one-sided PSD along X and along Y (periodic Hann, per-line mean,
                   S = d |rfft(w z)|^2 / (N U), doubled except at DC and Nyquist, mean over
                   lines), ripple at f0 = 1/3 mm^-1: sigma_k over |f - k f0| <= max(4 df, 0.1 f0)
                   for 5 harmonics, prominence over the median of the flanking bins, Y/X ratio.
  psd_2d_radial/N  the same removal, the map mean removed, separable Hann, two-sided 2-D PSD
                   from rfft2, radial PSD (bins of max(dfx, dfy), integrated and average forms).
  metrology/N      the full metrology of a map (issue 9): the same removal once, height
                   statistics of the residual (mean, Sq, Sa, Sp, Sv, Sz, Ssk, Sku as
                   bonnetlab_surface::height_stats: two passes, moments about the mean; the
                   fastest NumPy form: BLAS dot products for the third and fourth moments),
                   then psd_xy_ripple's PSDs and ripple on the same residual.
Two FFT back ends: numpy.fft (single thread) and scipy.fft with workers = all cores.
Prints one JSON object per line {"name", "backend", "n", "median_s", "runs", "sigma1_nm"}.
"""

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

try:
    import scipy.fft as sfft
except ImportError:  # SciPy is optional; NumPy alone still runs
    sfft = None

DX = 0.1
PITCH = 3.0


def synthetic(n):
    rng = np.random.default_rng(1)
    x = np.arange(n) * DX
    y = np.arange(n) * DX
    z = 10.0 * np.sin(2 * np.pi * y / PITCH)[:, None] + 0.3 * x[None, :] - 0.2 * y[:, None]
    return z + 2.0 * rng.standard_normal((n, n))


def remove_piston_tilt(z, dx, dy):
    ny, nx = z.shape
    x = np.arange(nx) * dx
    y = np.arange(ny) * dy
    half = 0.5 * max(x[-1] - x[0], y[-1] - y[0])
    u = (x - 0.5 * (x[0] + x[-1])) / half
    v = (y - 0.5 * (y[0] + y[-1])) / half
    su, sv = ny * u.sum(), nx * v.sum()
    a = np.array([
        [nx * ny, su, sv],
        [su, ny * (u * u).sum(), u.sum() * v.sum()],
        [sv, u.sum() * v.sum(), nx * (v * v).sum()],
    ])
    b = np.array([z.sum(), (z.sum(axis=0) * u).sum(), (z.sum(axis=1) * v).sum()])
    c = np.linalg.solve(a, b)
    return z - c[0] - c[1] * u[None, :] - c[2] * v[:, None]


def hann(n):
    return 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)


def psd1d(z, d, axis, rfft):
    n = z.shape[axis]
    w = hann(n)
    zz = z - z.mean(axis=axis, keepdims=True)
    zz *= w[None, :] if axis == 1 else w[:, None]
    spec = rfft(zz, axis=axis)
    p = (spec.real ** 2 + spec.imag ** 2).mean(axis=1 - axis)
    s = d * p / (n * (w ** 2).mean())
    s[1:(n + 1) // 2] *= 2.0
    f = np.arange(s.size) / (n * d)
    return f, s


def band_rms(f, p, f1, f2, df):
    eps = 1e-9 * df
    m = (f >= f1 - eps) & (f <= f2 + eps)
    return float(np.sqrt(p[m].sum() * df))


def ripple(fx, px, fy, py, pitch, harmonics=5):
    df = fy[1] - fy[0]
    f0 = 1.0 / pitch
    h = max(4 * df, 0.1 * f0)
    nyq = fy[-1]
    sig = [band_rms(fy, py, k * f0 - h, k * f0 + h, df)
           for k in range(1, harmonics + 1) if k * f0 <= nyq]
    eps = 1e-9 * df
    inb = np.abs(fy - f0) <= h + eps
    peak = py[inb].max()
    flank = max(2 * h, 8 * df)
    d = np.abs(fy - f0)
    bg = (d > h + eps) & (d <= h + flank + eps) & (fy >= 3 * df - eps)
    for k in range(2, harmonics + 1):
        bg &= ~(np.abs(fy - k * f0) <= h + eps)
    background = np.median(py[bg])
    sx = band_rms(fx, px, f0 - h, f0 + h, fx[1] - fx[0])
    return {
        "sigma1_nm": sig[0],
        "sigma_total_nm": float(np.sqrt(np.sum(np.square(sig)))),
        "a_eq_nm": np.sqrt(2) * sig[0],
        "prominence_db": float(10 * np.log10(peak / background)),
        "y_over_x": sig[0] / sx if sx > 0 else None,
    }


def psd_xy_ripple_of_residual(zr, rfft):
    fx, px = psd1d(zr, DX, 1, rfft)
    fy, py = psd1d(zr, DX, 0, rfft)
    return ripple(fx, px, fy, py, PITCH)


def psd_xy_ripple(z, rfft):
    return psd_xy_ripple_of_residual(remove_piston_tilt(z, DX, DX), rfft)


def height_stats(zr):
    d = zr.ravel()
    n = d.size
    mean = d.mean()
    d = d - mean
    d2 = d * d
    var = d2.sum() / n
    rms = np.sqrt(var)
    m3 = np.dot(d2, d) / n
    m4 = np.dot(d2, d2) / n
    hi, lo = float(d.max()), float(d.min())
    return {"mean_nm": float(mean), "rms_nm": float(rms), "sa_nm": float(np.abs(d).mean()),
            "sp_nm": hi, "sv_nm": -lo, "sz_nm": hi - lo,
            "ssk": float(m3 / (var * rms)), "sku": float(m4 / (var * var))}


def metrology(z, rfft):
    zr = remove_piston_tilt(z, DX, DX)
    st = height_stats(zr)
    r = psd_xy_ripple_of_residual(zr, rfft)
    r["rms_nm"] = st["rms_nm"]
    r["sku"] = st["sku"]
    return r


def psd_2d_radial(z, rfft2):
    ny, nx = z.shape
    zr = remove_piston_tilt(z, DX, DX)
    zr -= zr.mean()
    w2 = np.outer(hann(ny), hann(nx))
    zr *= w2
    spec = rfft2(zr)
    p = DX * DX * (spec.real ** 2 + spec.imag ** 2) / (w2 ** 2).sum()
    nh = nx // 2 + 1
    dfx, dfy = 1 / (nx * DX), 1 / (ny * DX)
    fx = np.arange(nh) * dfx
    fy = np.fft.fftfreq(ny, DX)
    wk = np.full(nh, 2.0)
    wk[0] = 1.0
    if nx % 2 == 0:
        wk[-1] = 1.0
    dfr = max(dfx, dfy)
    b = np.floor(np.sqrt(fx[None, :] ** 2 + fy[:, None] ** 2) / dfr + 0.5).astype(np.int64).ravel()
    sums = np.bincount(b, weights=(p * wk[None, :]).ravel())
    counts = np.bincount(b, weights=np.broadcast_to(wk[None, :], p.shape).ravel())
    integrated = sums * dfx * dfy / dfr
    average = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    return {"mean_square": float(integrated.sum() * dfr), "bins": int(average.size)}


def timed(fn, reps):
    times, out = [], None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), times, out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="512,1024,2048,4096")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--reps-large", type=int, default=3, help="repetitions at N >= 4096")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    backends = [("numpy", np.fft.rfft, np.fft.rfft2)]
    if sfft is not None:
        workers = os.cpu_count() or 1
        backends.append((f"scipy(workers={workers})",
                         lambda x, axis: sfft.rfft(x, axis=axis, workers=workers),
                         lambda x: sfft.rfft2(x, workers=workers)))
    lines = []
    for n in [int(s) for s in a.sizes.split(",")]:
        z = synthetic(n)
        reps = a.reps_large if n >= 4096 else a.reps
        for name, rfft, rfft2 in backends:
            med, runs, r = timed(lambda: psd_xy_ripple(z, rfft), reps)
            lines.append({"name": f"psd_xy_ripple/{n}", "backend": name, "n": n, "median_s": med,
                          "runs": runs, "sigma1_nm": r["sigma1_nm"],
                          "prominence_db": r["prominence_db"]})
            print(json.dumps(lines[-1]), flush=True)
            med, runs, r = timed(lambda: metrology(z, rfft), reps)
            lines.append({"name": f"metrology/{n}", "backend": name, "n": n, "median_s": med,
                          "runs": runs, "sigma1_nm": r["sigma1_nm"], "rms_nm": r["rms_nm"],
                          "sku": r["sku"]})
            print(json.dumps(lines[-1]), flush=True)
            med, runs, r = timed(lambda: psd_2d_radial(z, rfft2), reps)
            lines.append({"name": f"psd_2d_radial/{n}", "backend": name, "n": n, "median_s": med,
                          "runs": runs, "mean_square": r["mean_square"]})
            print(json.dumps(lines[-1]), flush=True)
        del z
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        with open(a.out, "w") as fh:
            for l in lines:
                fh.write(json.dumps(l) + "\n")
    print(f"numpy {np.__version__}, python {sys.version.split()[0]}", file=sys.stderr)


if __name__ == "__main__":
    main()
