#!/usr/bin/env python3
"""Whether two `lipac compare` report folders hold the same figures, timings aside.

    python3 lipac-sim/benches/same_figures.py BEFORE_DIR AFTER_DIR

Compares report.json and frames.csv field by field. Masked (measured on the
CPU, different in every run): every field named `*_ms` except the modelled
`gpu_*` ones, `wall_s`, and `blas_throughput` (the measured obvhs rates).
Exits 0 when everything else is identical, 1 with the first differences.
"""
import csv
import json
import sys


def timing(key):
    return (key.endswith("_ms") and not key.startswith("gpu_")) or key in (
        "wall_s",
        "blas_throughput",
    )


def mask(v):
    if isinstance(v, dict):
        return {k: ("<timing>" if timing(k) else mask(x)) for k, x in v.items()}
    if isinstance(v, list):
        return [mask(x) for x in v]
    return v


def diffs(a, b, path=""):
    if type(a) is not type(b):
        yield f"{path}: {a!r} != {b!r}"
    elif isinstance(a, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                yield f"{path}.{k}: only in {'after' if k in b else 'before'}"
            else:
                yield from diffs(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        if len(a) != len(b):
            yield f"{path}: {len(a)} != {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b)):
            yield from diffs(x, y, f"{path}[{i}]")
    elif a != b:
        yield f"{path}: {a!r} != {b!r}"


def frames(path):
    with open(path, newline="") as f:
        return [{k: ("<timing>" if timing(k) else v) for k, v in row.items()} for row in csv.DictReader(f)]


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    before, after = sys.argv[1:]
    found = []
    with open(f"{before}/report.json") as f:
        a = mask(json.load(f))
    with open(f"{after}/report.json") as f:
        b = mask(json.load(f))
    found += list(diffs(a, b, "report.json"))
    found += list(diffs(frames(f"{before}/frames.csv"), frames(f"{after}/frames.csv"), "frames.csv"))
    if found:
        print(f"{len(found)} differences, the first:")
        print("\n".join(found[:20]))
        sys.exit(1)
    rows = len(frames(f"{after}/frames.csv"))
    print(f"same figures: report.json and frames.csv ({rows} rows) identical, timings aside")


if __name__ == "__main__":
    main()
