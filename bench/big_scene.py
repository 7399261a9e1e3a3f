"""Real-size benchmark scenes (1-6 M Gaussians) built from the shared captures: copies of the
object scenes, each normalised to a unit box, placed side by side on a grid.

    .venv/bin/python bench/big_scene.py --gaussians 1.2M --sh 3 [--noise] -o bench/.cache/big_1.2M_sh3.ply
    .venv/bin/python bench/big_scene.py --gaussians 1.2M --objects tiny_graphdeco_iter7000_sh3 --noise -o ...

SH degree 3: copies of measuring_jug (SH 3), flowers_daffodils (SH 2, band 3 zero), the showroom
crop (SH 0, bands 1-3 zero) and tiny_graphdeco (SH 3); degree 2: flowers, the jug cut to
degree 2, the showroom crop.  Copies cycle through the list until the count is reached (the last
copy is cut to the exact count, keeping its most opaque Gaussians).  ``--noise`` moves every
copy off the delivery grid with bench_codec's noise (a different seed per copy), so copies are
not bit-identical either.  ``--objects`` names the copies' scenes instead: the trained tiny
scene alone (noised, so that copies differ) stands in for a real-size trained capture, whose SH
rest the delivery-format scenes above do not resemble (docs/design/sh-klt.md).  Deterministic:
the same arguments give the same file.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import add_noise  # noqa: E402

OBJECTS = {3: ["measuring_jug_sh3", "flowers_daffodils_sh2", "showroom_lacadiere_crop_sh0",
               "tiny_graphdeco_iter7000_sh3"],
           2: ["flowers_daffodils_sh2", "measuring_jug_sh3", "showroom_lacadiere_crop_sh0"]}
SPACING = 1.25       # grid pitch in units of a normalised object's box


def parse_count(text: str) -> int:
    t = text.strip().upper()
    mult = {"K": 1_000, "M": 1_000_000}.get(t[-1:], 1)
    return int(round(float(t.rstrip("KM")) * mult))


def normalised(cloud, degree: int):
    """The cloud centred on its robust (1-99 %) box, scaled so that box's largest side is 1,
    with its SH cut or zero-padded to ``degree``."""
    from gsz.decoder.cloud import GaussianCloud, sh_rest_count
    lo, hi = np.percentile(cloud.positions, [1, 99], axis=0)
    s = 1.0 / float((hi - lo).max())
    k = sh_rest_count(degree)
    rest = np.zeros((len(cloud), k, 3), np.float32)
    have = min(k, cloud.sh_rest.shape[1])
    rest[:, :have] = cloud.sh_rest[:, :have]
    return GaussianCloud(positions=(cloud.positions - (lo + hi) / 2) * s,
                         scales=cloud.scales + np.float32(np.log(s)), rotations=cloud.rotations,
                         opacities=cloud.opacities, sh_dc=cloud.sh_dc, sh_rest=rest, sh_degree=degree)


def build(n: int, degree: int, noise: bool, progress=print, names: list | None = None):
    """A GaussianCloud of exactly ``n`` Gaussians (see the module docstring); ``names``: the
    shared scenes to copy (default OBJECTS[degree])."""
    from gsz.decoder.cloud import GaussianCloud
    from gsz.decoder.ply import read_ply
    objects = [normalised(read_ply(SHARED / f"{name}.ply"), degree) for name in names or OBJECTS[degree]]
    parts, total, i = [], 0, 0
    while total < n:
        obj = objects[i % len(objects)]
        if noise:
            obj = add_noise(obj, seed=i)
        take = min(len(obj), n - total)
        if take < len(obj):
            keep = np.sort(np.lexsort((np.arange(len(obj)), -obj.opacities))[:take])
            obj = obj.subset(keep)
        parts.append((i, obj))
        total += take
        i += 1
    side = int(np.ceil(np.sqrt(len(parts))))
    fields = {k: [] for k in ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")}
    for i, obj in parts:
        offset = np.array([(i % side) * SPACING, 0.0, (i // side) * SPACING], np.float32)
        fields["positions"].append(obj.positions + offset)
        for k in ("scales", "rotations", "opacities", "sh_dc", "sh_rest"):
            fields[k].append(getattr(obj, k))
    progress(f"{len(parts)} copies on a {side} x {side} grid, {total:,} Gaussians, SH degree {degree}")
    return GaussianCloud(**{k: np.concatenate(v) for k, v in fields.items()}, sh_degree=degree)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gaussians", default="1.2M", help="count, e.g. 1.2M, 3M, 6M, 800k")
    ap.add_argument("--sh", type=int, default=3, choices=[2, 3])
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--objects", default=None, help="comma list of shared scene stems to copy (default: the list above)")
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args(argv)
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    from gsz.decoder.ply import write_ply
    names = a.objects.split(",") if a.objects else None
    for name in names or []:
        if not (SHARED / f"{name}.ply").exists():
            print(f"big_scene: no shared scene {name!r} in {SHARED}", file=sys.stderr)
            return 2
    cloud = build(parse_count(a.gaussians), a.sh, a.noise, names=names)
    Path(a.output).parent.mkdir(parents=True, exist_ok=True)
    write_ply(cloud, a.output)
    print(f"wrote {a.output}: {Path(a.output).stat().st_size:,} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
