"""Prints criterion medians (target/criterion/spectrum/...) next to the peer medians and the
speed-up ratios, as a Markdown table. Usage: compare.py CRITERION_DIR PEERS.jsonl"""

import json
import os
import sys


def criterion_median_s(root, name):
    group, bench, n = "spectrum", *name.split("/")
    p = os.path.join(root, group, bench, n, "new", "estimates.json")
    if not os.path.exists(p):
        return None
    with open(p) as fh:
        return json.load(fh)["median"]["point_estimate"] * 1e-9


def main():
    root, peers = sys.argv[1], sys.argv[2]
    rows = {}
    with open(peers) as fh:
        for line in fh:
            r = json.loads(line)
            rows.setdefault(r["name"], {})[r["backend"]] = r["median_s"]
    backends = sorted({b for v in rows.values() for b in v})
    head = "| workload | bonnetlab (ms) | " + " | ".join(f"{b} (ms) | ratio vs {b}" for b in backends) + " |"
    print(head)
    print("|" + "---|" * (2 + 2 * len(backends)))
    def key(name):
        w, n = name.split("/")
        return (w, int(n))
    for name in sorted(rows, key=key):
        ours = criterion_median_s(root, name)
        cells = [name, f"{ours * 1e3:.1f}" if ours else "n/a"]
        for b in backends:
            t = rows[name].get(b)
            cells.append(f"{t * 1e3:.1f}" if t else "n/a")
            cells.append(f"{t / ours:.1f}x" if t and ours else "n/a")
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
