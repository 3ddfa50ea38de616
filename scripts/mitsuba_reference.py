#!/usr/bin/env python3
"""Reference values of Mitsuba 3's `measured` BSDF for the RGL RGB files.

For every `*_rgb.bsdf` in the data folder, evaluates Mitsuba 3 (variant `scalar_rgb`) at seeded
random direction pairs and writes `<material>.csv` with columns
`wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,R,G,B`, where R, G, B are the BRDF f = eval / cos(theta_o) in 1/sr
(Mitsuba's `measured` eval returns f cos(theta_o)).

Directions are rounded to float32 before evaluation and written exactly, so a float64 evaluator
sees the same inputs as Mitsuba. The pairs mix uniform elevations up to 89 degrees, grazing pairs
(75-89 degrees) and near-specular pairs (wo close to the mirror direction of wi).

Usage (PyPI: `pip install mitsuba numpy`; tested with mitsuba 3.9.1, drjit 1.5.0):
    python3 scripts/mitsuba_reference.py [DATA_DIR] [OUT_DIR] [--pairs N] [--seed S]
Defaults: ../shared/data/rgl-rgb, crates/brdf-io/tests/data/mitsuba, 200 pairs, seed 20181204.
"""
import argparse
import glob
import math
import os

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")


def direction(theta, phi):
    s = math.sin(theta)
    v = np.array([s * math.cos(phi), s * math.sin(phi), math.cos(theta)], dtype=np.float64)
    return (v / np.linalg.norm(v)).astype(np.float32)


def pairs(rng, n):
    """n (wi, wo) pairs: 40 % uniform, 30 % grazing, 30 % near-specular."""
    max_t = math.radians(89.0)
    out = []
    for k in range(n):
        kind = k % 10
        if kind < 4:
            ti, to = rng.uniform(0, max_t, 2)
            pi_, po = rng.uniform(-math.pi, math.pi, 2)
        elif kind < 7:
            ti = rng.uniform(math.radians(75), max_t)
            to = rng.uniform(0, max_t) if kind == 4 else rng.uniform(math.radians(75), max_t)
            pi_, po = rng.uniform(-math.pi, math.pi, 2)
        else:
            ti = rng.uniform(0, max_t)
            to = min(max(ti + rng.normal(0, 0.05), 0.0), max_t)
            pi_ = rng.uniform(-math.pi, math.pi)
            po = pi_ + math.pi + rng.normal(0, 0.08)
        out.append((direction(ti, pi_), direction(to, po)))
    return out


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(here)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", default=os.path.join(root, "..", "shared", "data", "rgl-rgb"))
    ap.add_argument("out", nargs="?", default=os.path.join(root, "crates", "brdf-io", "tests", "data", "mitsuba"))
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=20181204)
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    ctx = mi.BSDFContext()
    files = sorted(glob.glob(os.path.join(args.data, "*_rgb.bsdf")))
    if not files:
        raise SystemExit(f"no *_rgb.bsdf files in {args.data}")
    for path in files:
        name = os.path.basename(path)[: -len(".bsdf")]
        bsdf = mi.load_dict({"type": "measured", "filename": path})
        rng = np.random.default_rng([args.seed, len(name)] + [ord(c) for c in name])
        rows = []
        for wi, wo in pairs(rng, args.pairs):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*[float(x) for x in wi])
            v = bsdf.eval(ctx, si, mi.Vector3f(*[float(x) for x in wo]))
            cos_o = float(wo[2])
            rgb = [float(v[c]) / cos_o for c in range(3)]
            rows.append([float(x) for x in wi] + [float(x) for x in wo] + rgb)
        out = os.path.join(args.out, name + ".csv")
        with open(out, "w") as f:
            f.write(f"# Mitsuba {mi.__version__} measured BSDF (scalar_rgb), f = eval / cos(theta_o), seed {args.seed}\n")
            f.write("wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,R,G,B\n")
            for r in rows:
                f.write(",".join("%.9g" % x for x in r) + "\n")
        print(f"wrote {out} ({len(rows)} pairs)")


if __name__ == "__main__":
    main()
