#!/usr/bin/env python3
"""Loads a Bonn .btf written by `btfrig dataset export` with the PyPI package btf-extractor
(its Ubo2014 class, a wrapper of zeroeffects/btf's btf.hh) and compares every texel it
returns, for the (light, view) pairs of a reference file, with btfrig's own decoder, and the
light and view directions it reports with the dataset's (angular distance).

usage: check_btf_extractor.py FILE.btf REFERENCE.json

REFERENCE.json (written by the cargo test tests/compress_extractor.rs):
  {"width": W, "height": H, "light": [[theta_deg, phi_deg], ...], "view": [...],
   "samples": [{"light": l, "view": v}, ...], "data": "REFERENCE.f32", "rel_tol": 1e-5,
   "max_angle_deg": 0.1}
REFERENCE.f32: for each sample, H x W x 3 little-endian float32, linear RGB, row 0 at the
top (btfrig's texture orientation), as btfrig_compress::ubo::Ubo::texel decodes the file.

Run it with the venv tests/install-deps.sh makes (target/pydeps/btf/bin/python: btf-extractor
and its dependencies pinned with hashes in tests/requirements/btf-extractor*.txt). Exit 0: every
direction within max_angle_deg of the dataset's (btf-extractor rounds its keys to 0.1 deg), one
btf-extractor direction per dataset direction, and every texel within tolerance.
"""
import json
import os
import sys



def import_btf_extractor():
    try:
        import btf_extractor  # noqa: F401
    except ImportError as e:
        sys.exit(f"{sys.executable} cannot import btf_extractor ({e}): run tests/install-deps.sh, and run this "
                 "script with target/pydeps/btf/bin/python")


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    btf_path, ref_path = sys.argv[1], sys.argv[2]
    import_btf_extractor()
    import numpy as np
    from btf_extractor import Ubo2014

    ref = json.load(open(ref_path))
    w, h = ref["width"], ref["height"]
    data = np.fromfile(os.path.join(os.path.dirname(ref_path), ref["data"]), dtype="<f4")
    data = data.reshape(len(ref["samples"]), h, w, 3)
    tol = ref.get("rel_tol", 1e-5)

    btf = Ubo2014(btf_path)
    keys = list(btf.angles_set)
    max_angle = ref.get("max_angle_deg", 0.1)

    def unit(d):
        t, p = np.radians(d[0]), np.radians(d[1])
        return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])

    def angle(a, b):
        return float(np.degrees(np.arccos(np.clip(unit(a) @ unit(b), -1.0, 1.0))))

    # The directions btf-extractor reports against the dataset's: as many, each dataset
    # direction with its own btf-extractor direction within max_angle.
    worst_angle = 0.0
    for name, dirs, have in (("light", ref["light"], {(k[0], k[1]) for k in keys}),
                             ("view", ref["view"], {(k[2], k[3]) for k in keys})):
        if len(have) != len(dirs):
            sys.exit(f"btf-extractor reports {len(have)} {name} directions, the dataset has {len(dirs)}")
        nearest = []
        for i, d in enumerate(dirs):
            dist, k = min((angle(d, k), k) for k in have)
            if dist > max_angle:
                sys.exit(f"{name} {i} (theta {d[0]:.3f}, phi {d[1]:.3f} deg): nearest btf-extractor direction {k} "
                         f"is {dist:.3f} deg away (allowed {max_angle})")
            worst_angle = max(worst_angle, dist)
            nearest.append(k)
        if len(set(nearest)) != len(dirs):
            sys.exit(f"two dataset {name} directions share one btf-extractor direction")

    def find(light, view):
        return min(keys, key=lambda k: angle(light, k[:2]) + angle(view, k[2:]))

    worst = 0.0
    for i, s in enumerate(ref["samples"]):
        key = find(ref["light"][s["light"]], ref["view"][s["view"]])
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
    print(f"btf-extractor {btf_path}: {len(ref['light'])} lights and {len(ref['view'])} views within "
          f"{worst_angle:.3f} deg of the dataset's (allowed {max_angle}); {len(ref['samples'])} (light, view) pairs "
          f"x {w * h} texels x 3 channels match btfrig's decoder, worst relative difference {worst:.2e} "
          f"(tolerance {tol})")


if __name__ == "__main__":
    main()
