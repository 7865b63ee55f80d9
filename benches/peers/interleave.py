"""Side-by-side timing that alternates bonnetlab and the NumPy peer, so both see the same
machine load (on a shared machine the load changes within seconds; the sequential run.sh can
put one side in a busy minute and the other in a quiet one).

Each round runs the bonnetlab example (crates/spectrum/examples/time_psd.rs, release, the
same map and work as benches/spectrum.rs) for `--reps` repetitions of a workload, then the
NumPy peer (psd_numpy.py, same conventions) for the same workload on the same size, and logs
the load average. Reports per side the minimum (closest to a quiet machine) and the median
over all repetitions of all rounds, and the ratio of each.
Usage: interleave.py EXAMPLE_BINARY [--size 4096] [--rounds 5] [--reps 3]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import psd_numpy as peer  # noqa: E402

WORKLOADS = {
    "psd_xy_ripple": lambda z: peer.psd_xy_ripple(z, np.fft.rfft),
    "metrology": lambda z: peer.metrology(z, np.fft.rfft),
}


def load():
    return os.getloadavg()[0]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("--size", type=int, default=4096)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    z = peer.synthetic(a.size)
    times = {(w, b): [] for w in WORKLOADS for b in ("bonnetlab", "numpy")}
    loads = []
    for r in range(a.rounds):
        for w, fn in WORKLOADS.items():
            out = subprocess.run([a.binary, str(a.size), str(a.reps), w], check=True,
                                 capture_output=True, text=True).stdout
            times[(w, "bonnetlab")] += json.loads(out)["runs"]
            for _ in range(a.reps):
                t = time.perf_counter()
                fn(z)
                times[(w, "numpy")].append(time.perf_counter() - t)
            loads.append(load())
        print(f"round {r + 1}/{a.rounds}: load {loads[-1]:.2f}", file=sys.stderr, flush=True)
    print(f"N = {a.size}, {a.rounds} rounds x {a.reps} reps per side, {os.cpu_count()} cores, "
          f"load average during the run {min(loads):.2f}-{max(loads):.2f}")
    print("| workload | bonnetlab min / median (ms) | numpy min / median (ms) | ratio of mins | ratio of medians |")
    print("|---|---|---|---|---|")
    for w in WORKLOADS:
        ours, theirs = times[(w, "bonnetlab")], times[(w, "numpy")]
        mo, mt = min(ours), min(theirs)
        do, dt = statistics.median(ours), statistics.median(theirs)
        print(f"| {w}/{a.size} | {mo * 1e3:.1f} / {do * 1e3:.1f} | {mt * 1e3:.1f} / {dt * 1e3:.1f} "
              f"| {mt / mo:.1f}x | {dt / do:.1f}x |")


if __name__ == "__main__":
    main()
