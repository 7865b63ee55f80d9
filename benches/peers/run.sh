#!/usr/bin/env bash
# Side-by-side timing of the spectral workloads: criterion (benches/spectrum.rs, release) and
# the NumPy / SciPy peer (psd_numpy.py) on the same machine, then a Markdown table of medians
# and ratios; at 4096 also interleave.py (the two sides alternate, so both see the same load).
# Last, prysm_peer.py: prysm 0.21.1 against `bonnetlab stats --remove piston,tilt` on the real
# Zygo files (shared/data/real).
# Creates its own virtual environment (benches/peers/.venv) on first use.
# Usage: benches/peers/run.sh [SIZES]   (SIZES default 512,1024,2048,4096)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
sizes="${1:-512,1024,2048,4096}"
venv="$here/.venv"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --upgrade pip
    "$venv/bin/pip" install --quiet numpy scipy prysm==0.21.1
fi
out="$root/target/peers"
mkdir -p "$out"
echo "== machine: $(nproc) cores, $(date -u +%Y-%m-%dT%H:%MZ), $(uptime | sed 's/.*load/load/')"
echo "== criterion (release): cargo bench --bench spectrum"
filter="spectrum/(psd_xy_ripple|metrology|psd_2d_radial)/($(echo "$sizes" | tr ',' '|'))$"
(cd "$root" && cargo bench --bench spectrum -- "$filter")
echo "== peer: NumPy / SciPy"
"$venv/bin/python" "$here/psd_numpy.py" --sizes "$sizes" --out "$out/psd_numpy.jsonl"
echo "== after the peer: $(uptime | sed 's/.*load/load/')"
echo "== medians side by side"
"$venv/bin/python" "$here/compare.py" "$root/target/criterion" "$out/psd_numpy.jsonl"
if [[ ",$sizes," == *",4096,"* ]]; then
    echo "== interleaved at 4096 (bonnetlab and NumPy alternate: same load)"
    (cd "$root" && cargo build --release -p bonnetlab-spectrum --example time_psd)
    "$venv/bin/python" "$here/interleave.py" "$root/target/release/examples/time_psd" --size 4096
fi
echo "== prysm peer: real Zygo files, read + piston/tilt + PV/RMS"
(cd "$root" && cargo build --release --bin bonnetlab)
"$venv/bin/python" "$here/prysm_peer.py" "$root/target/release/bonnetlab" "$root/../shared/data/real"
