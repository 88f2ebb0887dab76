"""The exact oracle's cost per pixel, by scene family: generated campaign scenes rendered whole by the
certified oracle (found by capability), each pixel certified and its robust bounds computed.

    .venv/bin/python benchmarks/bench_exact.py [--count 14] [--seed 38] [--size 32] [--out results.json]

Per family: microseconds per ray (one certified evaluation at rising precision, plus the robust one) --
min, median and max over the family's scenes -- the share of pixels certified at the first precision, the
exact ties, and the share of pixels the judge can settle (robust). One process, one thread; the wall time
of ``render`` (the Backend call), so Python's and python-flint's overheads are in it, as this process's CPU
time (single-threaded: on a shared machine the CPU time is what the work costs; the wall time is kept in
the JSON).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict

from minirt.campaign.campaign import scenes
from minirt.campaign.families import FAMILIES
from minirt.harness import backends, judge
from minirt.model.rules import resolve
from minirt.model.scene import parse_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=14, help="scenes (the families in turn)")
    ap.add_argument("--seed", type=int, default=38)
    ap.add_argument("--size", type=int, default=32, help="image side, pixels")
    ap.add_argument("--out", default=None, help="write the figures as JSON")
    args = ap.parse_args()
    name = judge.certified_oracle()
    if name is None:
        raise SystemExit("no certified oracle available")
    rows: dict[str, list[dict]] = defaultdict(list)
    for scene_name, fam, text in scenes(args.count, args.seed, list(FAMILIES), (args.size, args.size)):
        scene = parse_scene(text, f"{scene_name}.toml")
        rules = resolve(scene)
        t0, c0 = time.perf_counter(), time.process_time()
        res = backends.render(name, scene, rules)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if not res.ok:
            raise SystemExit(f"{scene_name}: {res.reason}")
        c = res.meta["certified"]
        n = c["pixels"]
        rows[fam].append({
            "scene": scene_name,
            "us_per_ray": 1e6 * cpu / n,
            "wall_us_per_ray": 1e6 * wall / n,
            "first_precision": c["bits"].get("128", 0) / n,
            "ties": c["ties"],
            "robust": float(res.aux["robust"].mean()),
        })  # fmt: skip
    table = {}
    print("| family | scenes | CPU µs per ray (min / median / max) | certified at 128 bits | ties | robust |")
    print("|---|---|---|---|---|---|")
    for fam in FAMILIES:
        r = rows.get(fam)
        if not r:
            continue
        us = sorted(x["us_per_ray"] for x in r)
        first = statistics.mean(x["first_precision"] for x in r)
        robust = statistics.mean(x["robust"] for x in r)
        ties = sum(x["ties"] for x in r)
        table[fam] = {"scenes": len(r), "us_per_ray": [us[0], statistics.median(us), us[-1]],
                      "first_precision": first, "ties": ties, "robust": robust}  # fmt: skip
        print(f"| {fam} | {len(r)} | {us[0]:.0f} / {statistics.median(us):.0f} / {us[-1]:.0f} | "
              f"{100 * first:.1f} % | {ties} | {100 * robust:.1f} % |")  # fmt: skip
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump({"size": args.size, "seed": args.seed, "families": table, "scenes": rows}, f, indent=1)


if __name__ == "__main__":
    main()
