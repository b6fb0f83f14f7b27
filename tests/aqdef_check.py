#!/usr/bin/env python3
"""An independent reader of the AQDEF (Q-DAS .dfq) export of `ris console`: parses the
K-field lines itself and checks that every value of the deviation statistics equals the
number in the scans' report.json files (given oldest first).

usage: aqdef_check.py EXPORT.dfq REPORT.json...
"""
import json
import sys


def parse(path):
    names = {}
    values = {}
    limits = {}
    count = None
    for raw in open(path, encoding="utf-8"):
        line = raw.rstrip("\n")
        if not line.strip():
            continue
        key, _, text = line.partition(" ")
        if key == "K0100":
            count = int(text)
            continue
        if "/" not in key:
            continue
        field, _, number = key.partition("/")
        k = int(number)
        if field == "K2001":
            names[k] = text
        elif field == "K0001":
            values.setdefault(k, []).append(float(text))
        elif field in ("K2110", "K2111"):
            limits[(k, field)] = float(text)
    if count != len(names):
        sys.exit(f"K0100 says {count} characteristics, {len(names)} are described")
    return {names[k]: values.get(k, []) for k in names}, limits, names


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    series, limits, names = parse(sys.argv[1])
    reports = [json.load(open(p, encoding="utf-8")) for p in sys.argv[2:]]
    checked = 0
    for name, key in (("mean", "mean"), ("rms", "rms"), ("p05", "p05"), ("p95", "p95"),
                      ("robust min", "robust_min"), ("robust max", "robust_max")):
        got = series.get(name)
        want = [r["statistics"][key] for r in reports]
        if got != want:
            sys.exit(f"{name}: the export has {got}, the reports {want}")
        checked += len(got)
    got = series.get("within tolerance")
    want = [100.0 * r["statistics"]["within_tolerance"] for r in reports]
    if got != want:
        sys.exit(f"within tolerance: the export has {got}, the reports {want}")
    checked += len(got)
    tol = reports[-1]["tolerance_mm"]
    k_mean = next(k for k, n in names.items() if n == "mean")
    if limits.get((k_mean, "K2110")) != -tol or limits.get((k_mean, "K2111")) != tol:
        sys.exit(f"mean's limits {limits.get((k_mean, 'K2110'))} … {limits.get((k_mean, 'K2111'))}, tolerance {tol}")
    print(f"{len(reports)} scans, {checked} values equal to report.json")


if __name__ == "__main__":
    main()
