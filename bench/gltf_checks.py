"""gsz's glTF files checked by independent tools (shared by bench/bench_gltf.py and
tests/test_gltf_peers.py).

The tools are npm packages installed into ``bench/.peers`` (git-ignored) by :func:`install`:

* ``gltf-validator`` -- the Khronos glTF-Validator;
* ``three`` -- three.js's GLTFLoader and its ``KHR_gaussian_splatting`` plugin (r187), an
  independent reader of the plain extension;
* ``@playcanvas/splat-transform`` -- PlayCanvas's converter, an independent *writer* of the plain
  extension (it reads no glTF: its .glb output is read by gsz instead).

``bench/gltf_peers.mjs`` runs the first two under node and hands their results back as JSON and
raw arrays; the comparisons against the values gsz started from are here.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PEERS = ROOT / "bench" / ".peers"
SCRIPT = ROOT / "bench" / "gltf_peers.mjs"
#: exact versions: splat-transform 3.x needs node >= 22; 2.7.1 already writes linear SCALE
PINS = {"gltf-validator": "2.0.0-dev.3.10", "three": "0.187.0", "@playcanvas/splat-transform": "2.7.1"}
SH_C0 = 0.28209479177387814


def node() -> str | None:
    return shutil.which("node")


def missing() -> list:
    """The pinned tools not installed in bench/.peers (all of them when node is absent)."""
    if node() is None:
        return list(PINS)
    return [p for p in PINS if not (PEERS / "node_modules" / p / "package.json").exists()]


def install(timeout: int = 600) -> tuple:
    """(ok, log tail) of ``npm install --prefix bench/.peers`` of the pinned tools."""
    npm = shutil.which("npm")
    if npm is None or node() is None:
        return False, "node/npm not found"
    cmd = [npm, "install", "--prefix", str(PEERS), "--no-audit", "--no-fund",
           *[f"{k}@{v}" for k, v in PINS.items()]]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"npm install timed out after {timeout} s"
    return p.returncode == 0 and not missing(), (p.stdout + p.stderr)[-2000:]


def _run(*args, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([node(), str(SCRIPT), *map(str, args)], capture_output=True, text=True, timeout=timeout)


# ----------------------------------------------------------------------------------- validator
def validate(paths) -> list:
    """The validator's report per file: numErrors, numWarnings, ..., messages."""
    p = _run("validate", *paths)
    if p.returncode != 0:
        raise RuntimeError(f"gltf-validator failed: {p.stderr[-1000:]}")
    return json.loads(p.stdout)


def known_limitation(message: dict) -> bool:
    """The validator (2.0.0-dev.3.10) rejects every extension-prefixed attribute name
    (KhronosGroup/glTF-Validator#252): an error on valid KHR_gaussian_splatting files."""
    return (message["code"] == "MESH_PRIMITIVE_INVALID_ATTRIBUTE"
            and "/attributes/KHR_gaussian_splatting:" in (message.get("pointer") or ""))


def unexplained(report: dict) -> list:
    """Errors and warnings (severity 0 and 1) other than the known limitation."""
    return [m for m in report["messages"] if m["severity"] <= 1 and not known_limitation(m)]


# ------------------------------------------------------------------------------------ three.js
def three_load(path, outdir) -> dict:
    """What three.js's GLTFLoader + KHR_gaussian_splatting plugin built from ``path``:
    {attribute: array}, plus "warnings" (the loader's console output)."""
    p = _run("three", path, outdir)
    if p.returncode != 0:
        raise RuntimeError(f"three.js failed on {path}: {p.stderr[-1000:]}")
    meta = json.loads((Path(outdir) / "meta.json").read_text())
    dtypes = {"Float32Array": np.float32, "Uint8ClampedArray": np.uint8, "Uint32Array": np.uint32}
    out = {"warnings": p.stderr.strip()}
    for name, m in meta["attributes"].items():
        raw = np.fromfile(Path(outdir) / f"{name}.bin", dtypes[m["type"]])
        out[name] = raw.reshape(m["count"], -1) if "count" in m else raw
    return out


def expected_from_cloud(cloud) -> dict:
    """What a KHR_gaussian_splatting renderer should build from ``cloud`` (RDF, graphdeco),
    computed here in float64 from the extension's text: centres and covariances in the glTF
    frame (180 degrees about z from RDF), RGBA bytes from the DC and the sigmoid, SH bytes
    (x * 128 + 128) with every order-m coefficient times (-1)^m."""
    flip = np.array([-1.0, -1.0, 1.0])
    q = cloud.rotations.astype(np.float64)
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    rot = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)
    m = rot * np.exp(cloud.scales.astype(np.float64))[:, None, :]
    cov = flip[None, :, None] * (m @ m.transpose(0, 2, 1)) * flip[None, None, :]
    alpha = 1 / (1 + np.exp(-cloud.opacities.astype(np.float64)))
    rgba = np.c_[(0.5 + SH_C0 * cloud.sh_dc.astype(np.float64)) * 255, alpha * 255]
    bands = {}
    for band in range(1, cloud.sh_degree + 1):
        lo = band * band - 1
        signs = np.array([(-1.0) ** abs(mm) for mm in range(-band, band + 1)])
        bands[band] = cloud.sh_rest[:, lo:lo + 2 * band + 1].astype(np.float64) * signs[None, :, None] * 128 + 128
    return {"position": cloud.positions.astype(np.float64) * flip,
            "covariance": cov[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]],
            "color": np.clip(rgba, 0, 255), "sh": bands}


def compare_three(got: dict, cloud) -> dict:
    """Largest differences between three.js's splats and :func:`expected_from_cloud`:
    centres (absolute), covariances (relative to each splat's largest entry), colour and SH bytes
    (8-bit levels; three rounds to nearest)."""
    exp = expected_from_cloud(cloud)
    cov = got["covariance"].astype(np.float64)
    scale = np.abs(exp["covariance"]).max(axis=1, keepdims=True)
    out = {"count": int(len(got["position"])),
           "position_abs": float(np.abs(got["position"] - exp["position"]).max()),
           "covariance_rel": float((np.abs(cov - exp["covariance"]) / scale).max()),
           "color_levels": float(np.abs(got["color"].astype(np.float64) - exp["color"]).max())}
    words = {1: 3, 2: 4, 3: 6}
    sh = 0.0
    for band, want in exp["sh"].items():
        raw = got[f"sphericalHarmonics{band}"].reshape(len(want), -1).view(np.uint8)[:, :words[band] * 4]
        mine = raw[:, :(2 * band + 1) * 3].reshape(len(want), 2 * band + 1, 3).astype(np.float64)
        sh = max(sh, float(np.abs(mine - np.clip(want, 0, 255)).max()))
    out["sh_levels"] = sh
    return out


# ------------------------------------------------------------------------------ splat-transform
def splat_transform_glb(ply, out) -> Path:
    """``ply`` converted to a KHR_gaussian_splatting .glb by splat-transform."""
    cli = PEERS / "node_modules" / "@playcanvas" / "splat-transform" / "bin" / "cli.mjs"
    p = subprocess.run([node(), str(cli), "-w", str(ply), str(out)], capture_output=True, text=True, timeout=600)
    if p.returncode != 0:
        raise RuntimeError(f"splat-transform failed: {(p.stdout + p.stderr)[-1000:]}")
    return Path(out)


def compare_clouds(back, cloud) -> dict:
    """Largest differences between a cloud read back from glTF and the original (GLTF.md §1.3
    quantities): positions/DC/rest absolute, rotations against the unit original (up to sign),
    log-scales absolute, logits relative to their §1.3 bound (<= 1 means within it)."""
    q = cloud.rotations.astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    r = back.rotations.astype(np.float64)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    v = cloud.opacities.astype(np.float64)
    sig = 1 / (1 + np.exp(-v))
    bound = 2.0 ** -24 / (1 - sig) + 2 * np.spacing(np.abs(cloud.opacities)).astype(np.float64)
    return {"count": len(back) == len(cloud) and back.sh_degree == cloud.sh_degree,
            "positions": float(np.abs(back.positions.astype(np.float64) - cloud.positions).max()),
            "rotations": float(np.minimum(np.abs(r - q).max(1), np.abs(r + q).max(1)).max()),
            "log_scales": float(np.abs(back.scales.astype(np.float64) - cloud.scales).max()),
            "logits_over_bound": float((np.abs(back.opacities - v) / bound).max()),
            "sh_dc": float(np.abs(back.sh_dc - cloud.sh_dc).max()),
            "sh_rest": float(np.abs(back.sh_rest - cloud.sh_rest).max()) if cloud.sh_degree else 0.0}
