#!/usr/bin/env python3
"""Loads a Bonn .btf written by `btfrig dataset export` with the PyPI package btf-extractor
(its Ubo2014 class, a wrapper of zeroeffects/btf's btf.hh) and compares every texel it
returns, for the (light, view) pairs of a reference file, with btfrig's own decoder.

usage: check_btf_extractor.py FILE.btf REFERENCE.json

REFERENCE.json (written by the cargo test tests/compress_extractor.rs):
  {"width": W, "height": H, "light": [[theta_deg, phi_deg], ...], "view": [...],
   "samples": [{"light": l, "view": v}, ...], "data": "REFERENCE.f32", "rel_tol": 1e-5}
REFERENCE.f32: for each sample, H x W x 3 little-endian float32, linear RGB, row 0 at the
top (btfrig's texture orientation), as btfrig_compress::ubo::Ubo::texel decodes the file.

Installs btf-extractor into target/pydeps/btf when `import btf_extractor` fails (its source
package pins numpy<1.20, which does not build on Python 3.11: numpy<2 and cython<3 first,
then btf-extractor without build isolation). Exit 0: every texel within tolerance.
"""
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PYDEPS = os.path.join(HERE, "..", "..", "target", "pydeps", "btf")


def ensure_btf_extractor():
    sys.path.insert(0, PYDEPS)
    try:
        import btf_extractor  # noqa: F401
        return
    except ImportError:
        pass
    os.makedirs(PYDEPS, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=PYDEPS)
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--target", PYDEPS]
    for args in (["numpy<2", "cython<3", "poetry-core", "setuptools", "wheel"],
                 ["--no-build-isolation", "btf-extractor"]):
        r = subprocess.run(pip + args, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"installing {' '.join(args)} into {PYDEPS} failed:\n{r.stderr}")
    import importlib
    importlib.invalidate_caches()
    import btf_extractor  # noqa: F401


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    btf_path, ref_path = sys.argv[1], sys.argv[2]
    ensure_btf_extractor()
    import numpy as np
    from btf_extractor import Ubo2014

    ref = json.load(open(ref_path))
    w, h = ref["width"], ref["height"]
    data = np.fromfile(os.path.join(os.path.dirname(ref_path), ref["data"]), dtype="<f4")
    data = data.reshape(len(ref["samples"]), h, w, 3)
    tol = ref.get("rel_tol", 1e-5)

    btf = Ubo2014(btf_path)
    keys = list(btf.angles_set)

    def key_of(d):
        # btf-extractor's keys: theta = acos z, phi = atan2(y, x) mod 360, rounded to 0.1 deg.
        t, p = np.radians(d[0]), np.radians(d[1])
        x, y, z = np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)
        return round(float(np.degrees(np.arccos(z))), 1), round(float(np.degrees(np.arctan2(y, x)) % 360), 1)

    def find(tl, pl, tv, pv):
        best = min(keys, key=lambda k: abs(k[0] - tl) + abs(((k[1] - pl + 180) % 360) - 180)
                   + abs(k[2] - tv) + abs(((k[3] - pv + 180) % 360) - 180))
        return best

    worst = 0.0
    for i, s in enumerate(ref["samples"]):
        tl, pl = key_of(ref["light"][s["light"]])
        tv, pv = key_of(ref["view"][s["view"]])
        key = find(tl, pl, tv, pv)
        img = np.asarray(btf.angles_to_image(*key), dtype=np.float64)
        if img.shape != (h, w, 3):
            sys.exit(f"sample {i}: btf-extractor image shape {img.shape}, expected {(h, w, 3)}")
        rgb = img[..., ::-1]  # btf-extractor returns BGR
        want = data[i].astype(np.float64)
        peak = max(np.abs(want).max(), 1e-30)
        err = np.abs(rgb - want) / np.maximum(np.abs(want), 0.01 * peak)
        e = float(err.max())
        worst = max(worst, e)
        if e > tol:
            y, x, c = np.unravel_index(np.argmax(err), err.shape)
            as_rgb = float((np.abs(img - want) / np.maximum(np.abs(want), 0.01 * peak)).max())
            sys.exit(f"sample {i} (light {s['light']}, view {s['view']}, key {key}): texel (x {x}, y {y}) channel {c}: "
                     f"btf-extractor {rgb[y, x, c]} vs btfrig {want[y, x, c]}, relative {e:.3g} > {tol} "
                     f"(reading the image as RGB instead of BGR: {as_rgb:.3g})")
    print(f"btf-extractor {btf_path}: {len(ref['samples'])} (light, view) pairs x {w * h} texels x 3 channels "
          f"match btfrig's decoder, worst relative difference {worst:.2e} (tolerance {tol})")


if __name__ == "__main__":
    main()
