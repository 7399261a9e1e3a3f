"""Rebuild the fixtures of tests/test_formats_input.py: small scenes written by the tools users
have (see README.md here for the versions used).

    npm install --prefix NODE @playcanvas/splat-transform@3.10.2 @mkkellogg/gaussian-splats-3d@0.4.7 three
    python tests/data/formats/make_fixtures.py NODE

NODE is the folder holding node_modules.  The two source scenes are fixed subsets of the
committed samples (:func:`subsets`, which the tests recompute); .splat and the nerfstudio
"rgb" PLY, which neither tool writes, are written here following their reference exporters.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.dirname(HERE)
sys.path.insert(0, os.path.dirname(os.path.dirname(DATA)))


def subsets():
    """The two source scenes: every 12th Gaussian of the SH-3 jug (1,000) and every 10th of the
    SH-0 houseplant (2,000)."""
    import gsz
    jug = gsz.read_ply(os.path.join(DATA, "measuring_jug_sh3_12k.ply"))
    plant = gsz.read_ply(os.path.join(DATA, "houseplant_sh0_20k.ply"))
    return jug.subset(np.arange(0, len(jug), 12)), plant.subset(np.arange(0, len(plant), 10))


def write_splat(cloud, path):
    """antimatter15's convert.py, vectorised: rows sorted by -exp(sum of log-scales) * sigmoid
    (opacity), colour and alpha truncated to bytes, rotation bytes q / |q| * 128 + 128."""
    C0 = 0.28209479177387814
    order = np.argsort(-np.exp(cloud.scales.astype(np.float64).sum(axis=1))
                       / (1 + np.exp(-cloud.opacities.astype(np.float64))), kind="stable")
    c = cloud.subset(order)
    rows = np.zeros(len(c), [("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    rows["pos"] = c.positions
    rows["scale"] = np.exp(c.scales)
    colour = np.concatenate([0.5 + C0 * c.sh_dc.astype(np.float64),
                             1 / (1 + np.exp(-c.opacities.astype(np.float64)))[:, None]], axis=1)
    rows["rgba"] = (colour * 255).clip(0, 255).astype(np.uint8)
    q = c.rotations / np.linalg.norm(c.rotations, axis=1, keepdims=True)
    rows["rot"] = (q * 128 + 128).clip(0, 255).astype(np.uint8)
    with open(path, "wb") as f:
        f.write(rows.tobytes())


def write_nerfstudio_rgb(cloud, path):
    """nerfstudio's ns-export gaussian-splat --ply-color-mode rgb: x y z nx ny nz, then
    red green blue as uchar (clamped colour * 255, truncated), opacity, scale_*, rot_*."""
    from plyfile import PlyData, PlyElement
    C0 = 0.28209479177387814
    colours = (np.clip(cloud.sh_dc * C0 + 0.5, 0.0, 1.0) * 255).astype(np.uint8)
    names = ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    v = np.zeros(len(cloud), [(n, "u1" if n in ("red", "green", "blue") else "<f4") for n in names])
    for i, n in enumerate("xyz"):
        v[n] = cloud.positions[:, i]
    for i, n in enumerate(("red", "green", "blue")):
        v[n] = colours[:, i]
    v["opacity"] = cloud.opacities
    for i in range(3):
        v[f"scale_{i}"] = cloud.scales[:, i]
    for i in range(4):
        v[f"rot_{i}"] = cloud.rotations[:, i]
    PlyData([PlyElement.describe(v, "vertex")]).write(path)


def _beside(node_root, script):
    """A copy of ``script`` in ``node_root``: node resolves an ES module's imports from where the
    module lies (NODE_PATH does not apply to them)."""
    import shutil
    dst = os.path.join(node_root, "_gsz_" + script)
    shutil.copyfile(os.path.join(HERE, script), dst)
    return dst


def main(node_root):
    import gsz
    jug, plant = subsets()
    st = ["node", os.path.join(node_root, "node_modules/@playcanvas/splat-transform/bin/cli.mjs"), "-w", "-q"]
    env = dict(os.environ, NODE_PATH=os.path.join(node_root, "node_modules"))
    with tempfile.TemporaryDirectory() as tmp:
        src = {name: os.path.join(tmp, f"{name}.ply") for name in ("jug", "plant")}
        gsz.write_ply(jug, src["jug"])
        gsz.write_ply(plant, src["plant"])

        def out(name):
            return os.path.join(HERE, name)

        def run(*args):
            subprocess.run(list(args), check=True, env=env, cwd=node_root)

        # splat-transform: SPZ 3 and 4, compressed PLY, SOG bundled and unbundled
        run(*st, "--spz-version", "3", src["jug"], out("jug_v3.spz"))
        run(*st, src["jug"], out("jug_v4.spz"))
        run(*st, src["plant"], out("plant_v4.spz"))
        run(*st, src["jug"], out("jug.compressed.ply"))
        run(*st, src["plant"], out("plant.compressed.ply"))
        run(*st, "-g", "cpu", src["jug"], out("jug.sog"))
        os.makedirs(out("plant_sog"), exist_ok=True)
        run(*st, "-g", "cpu", src["plant"], out("plant_sog/meta.json"))
        # the official SPZ library (@adobe/spz, which splat-transform bundles): version 2, and a
        # file converted to SPZ's documented RUB frame
        spz = ["node", _beside(node_root, "write_spz.mjs")]
        run(*spz, src["jug"], out("jug_v2.spz"), "2", "UNSPECIFIED")
        run(*spz, src["jug"], out("jug_v3_rub.spz"), "3", "RDF")
        # GaussianSplats3D: compression levels 0-2 with SH degrees 0-2
        ks = ["node", _beside(node_root, "write_ksplat.mjs")]
        run(*ks, src["plant"], out("plant_l0.ksplat"), "0", "0")
        run(*ks, src["jug"], out("jug_l1_sh1.ksplat"), "1", "1")
        run(*ks, src["jug"], out("jug_l2_sh2.ksplat"), "2", "2")
    write_splat(plant, out("plant.splat"))
    write_nerfstudio_rgb(jug, out("jug_rgb.ply"))


if __name__ == "__main__":
    main(os.path.abspath(sys.argv[1]))
