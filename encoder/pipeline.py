"""The MesonGS++ encode pipeline at an explicit configuration.

    encode(cloud, EncodeOptions(reserve=0.8, bits=12)) -> EncodeResult(data=b"...", report={...})

Stages (each timed, progress on stderr):
 1. importance   I = I_d * (V / V_ref)^beta over the train views (reference renderer)
 2. prune        keep the top reserve*N Gaussians
 3. voxelize     octree depth (auto from a position-error budget, or given), merge per voxel
 4. geometry     octree occupancy, context-coded (GEOM chunk)
 5. attributes   quaternion -> Euler, RAHT of opacity/Euler/DC, group-wise quantisation of the
                 AC coefficients and the log-scales, rANS (ATTR chunk)
 6. sh           importance-weighted VQ of the higher SH + kept exact vectors (SHVQ chunk)
 7. container    header, chunk table, checksums, META JSON
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from gsz.decoder.attributes import attributes_from_channels
from gsz.decoder.bytesio import Writer
from gsz.decoder.cloud import GaussianCloud
from gsz.decoder.container import CHUNK_REQUIRED, FRAME_RDF, FileHeader, Chunk, write_container
from gsz.decoder.errors import GszError
from gsz.decoder.layout import (CHUNK_ATTR, CHUNK_GEOM, CHUNK_META, CHUNK_SHVQ, RAHT_CHANNELS,
                                ROTATION_EULER_ZYX)
from gsz.decoder.morton import morton_encode
from gsz.decoder.raht import build_raht_tree
from gsz.decoder.rotation import quaternion_to_euler
from gsz.decoder.sh import MAX_CODEBOOK

from .geometry import write_geometry
from .groups import write_channel_set
from .progress import Progress


class EncodeOptionsError(GszError, ValueError):
    """An encoder option is out of range."""


@dataclass
class EncodeOptions:
    """Every knob of the codec at a fixed configuration (the size search chooses them later).

    reserve          tau: fraction of Gaussians kept after importance pruning, (0, 1]
    bits             uniform bit-width of every quantisation group, 1..16
    codebook         SH VQ codebook size K (1..65536); capped at one codeword per 8 Gaussians
    keep             number of most important Gaussians whose exact SH vectors are kept
                     (None: 1 % of the voxels)
    blocks           blocks per quantised channel (groups = channels x blocks)
    depth            octree depth 1..21 (None: chosen from the position-error budget)
    rel_error        position-error budget relative to the robust scene diagonal (auto depth)
    beta             exponent of the volume term of the importance
    sh_bits          bit-width of SH codebook / kept vectors (None: same as ``bits``)
    train_views      number of default train cameras (when no camera file is given)
    importance_width render width of the importance pass
    vq_iters         mini-batch k-means iterations
    seed             RNG seed (VQ); the same input and options give byte-identical output
    """

    reserve: float = 0.8
    bits: int = 12
    codebook: int = 4096
    keep: int | None = None
    blocks: int = 80
    depth: int | None = None
    rel_error: float | None = None
    beta: float = 0.1
    sh_bits: int | None = None
    train_views: int = 24
    importance_width: int = 400
    vq_iters: int | None = None
    seed: int = 0

    def validate(self) -> "EncodeOptions":
        def bad(msg):
            raise EncodeOptionsError(msg)
        if not (0.0 < float(self.reserve) <= 1.0):
            bad(f"--reserve must be in (0, 1], got {self.reserve}")
        if not (1 <= int(self.bits) <= 16):
            bad(f"--bits must be 1..16, got {self.bits}")
        if self.sh_bits is not None and not (1 <= int(self.sh_bits) <= 16):
            bad(f"--sh-bits must be 1..16, got {self.sh_bits}")
        if not (1 <= int(self.codebook) <= MAX_CODEBOOK):
            bad(f"--codebook must be 1..{MAX_CODEBOOK}, got {self.codebook}")
        if self.keep is not None and int(self.keep) < 0:
            bad(f"--keep must be >= 0, got {self.keep}")
        if not (1 <= int(self.blocks) <= 65535):
            bad(f"--blocks must be 1..65535, got {self.blocks}")
        if self.depth is not None and not (1 <= int(self.depth) <= 21):
            bad(f"--depth must be 1..21, got {self.depth}")
        if self.rel_error is not None and not (float(self.rel_error) > 0):
            bad(f"--rel-error must be > 0, got {self.rel_error}")
        if not (float(self.beta) >= 0):
            bad(f"--beta must be >= 0, got {self.beta}")
        if int(self.train_views) < 1:
            bad(f"--train-views must be >= 1, got {self.train_views}")
        if int(self.importance_width) < 16:
            bad(f"--importance-width must be >= 16, got {self.importance_width}")
        return self


@dataclass
class EncodeResult:
    data: bytes
    cloud: GaussianCloud          # what the decoder will reconstruct (for reports / evaluation)
    report: dict = field(default_factory=dict)


def _top_k_mask(importance: np.ndarray, k: int) -> np.ndarray:
    """Mask of the k most important entries; ties broken by lower index (deterministic)."""
    mask = np.zeros(importance.shape[0], bool)
    if k > 0:
        order = np.lexsort((np.arange(importance.shape[0]), -importance))
        mask[order[:k]] = True
    return mask


@dataclass
class Stage:
    """Everything that depends on the reserve ratio and depth but not on bit-widths.

    vox        the voxelised, merged cloud (M Gaussians, Morton order)
    geometry   GEOM chunk payload (exact bytes)
    tree       RAHT tree of the voxels
    raht_dc    [7] float64 RAHT root coefficients (stored exactly)
    raht_ac    [7, M-1] float32 AC coefficients in stream (level) order
    scales     [3, M] float32 log-scales in Morton order
    sh         [M, D] float32 higher-degree SH vectors (D = 0 for SH degree 0)
    importance [M] float64 merged importance
    """

    reserve: float
    depth: int
    vox: object
    geometry: bytes
    tree: object
    raht_dc: np.ndarray
    raht_ac: np.ndarray
    scales: np.ndarray
    sh: np.ndarray
    importance: np.ndarray
    sh_degree: int
    input_gaussians: int

    @property
    def num_points(self) -> int:
        return len(self.vox.ijk)


def prepare_stage(cloud: GaussianCloud, importance: np.ndarray, reserve: float, *, depth=None,
                  rel_error=None, progress: Progress | None = None) -> Stage:
    """Prune to ``reserve``, voxelise, code the geometry and transform the attributes."""
    from .importance import prune
    from .raht import raht_forward
    from .voxelize import DEFAULT_REL_ERROR, choose_depth, voxelize

    progress = progress or Progress(quiet=True)
    with progress.stage("prune", f"reserve {reserve}"):
        kept = prune(importance, reserve)
        pruned = cloud.subset(kept)
        imp = importance[kept]
    with progress.stage("voxelize"):
        rel = DEFAULT_REL_ERROR if rel_error is None else float(rel_error)
        d = int(depth) if depth is not None else choose_depth(pruned.positions, rel_error=rel)
        vox = voxelize(pruned, imp, d)
        progress.log(f"depth {d}: {len(pruned)} Gaussians -> {len(vox.ijk)} voxels "
                     f"({100 * vox.merged_fraction:.2f} % merged)")
    with progress.stage("geometry"):
        geom = write_geometry(vox.ijk, vox.origin, vox.side, d)
    with progress.stage("transform", "Euler + RAHT"):
        c = vox.cloud
        tree = build_raht_tree(morton_encode(vox.ijk), d)
        euler = quaternion_to_euler(c.rotations.astype(np.float64))
        attrs = np.concatenate([c.opacities.astype(np.float64)[:, None], euler,
                                c.sh_dc.astype(np.float64)], axis=1)
        dc, ac = raht_forward(attrs, tree)
    m = len(vox.ijk)
    return Stage(reserve=float(reserve), depth=d, vox=vox, geometry=geom, tree=tree, raht_dc=dc,
                 raht_ac=np.ascontiguousarray(ac.T, dtype=np.float32),
                 scales=np.ascontiguousarray(c.scales.T, dtype=np.float32),
                 sh=c.sh_rest.reshape(m, -1).astype(np.float32), importance=vox.importance,
                 sh_degree=cloud.sh_degree, input_gaussians=len(cloud))


def attribute_chunk(stage: Stage, raht_bits, scale_bits, blocks: int):
    """ATTR chunk payload for the given bit-widths (int, or [7, B] / [3, B] arrays), the
    attributes the decoder will reconstruct, and per-part byte counts."""
    from gsz.decoder.raht import raht_inverse

    w = Writer()
    w.u8(ROTATION_EULER_ZYX).u8(len(RAHT_CHANNELS)).array(stage.raht_dc, np.float64)
    ac_bytes, ac_rec = write_channel_set(stage.raht_ac, raht_bits, blocks)
    sc_bytes, sc_rec = write_channel_set(stage.scales, scale_bits, blocks)
    w.bytes(ac_bytes).bytes(sc_bytes)
    decoded = attributes_from_channels(raht_inverse(stage.raht_dc, ac_rec.T, stage.tree), sc_rec)
    return w.getvalue(), decoded, {"raht_bytes": len(ac_bytes), "scale_bytes": len(sc_bytes)}


def default_codebook_size(m: int, requested: int | None = None) -> int:
    """K: the requested size, capped so that the codebook stays small next to its users
    (at most one codeword per 8 Gaussians, at least 16)."""
    k = 4096 if requested is None else int(requested)
    return max(1, min(k, max(16, m // 8), m))


def train_sh_codebook(stage: Stage, size: int, *, seed: int = 0, iters=None,
                      progress: Progress | None = None) -> np.ndarray:
    """Importance-weighted VQ codebook [K, D] of the stage's SH vectors."""
    from .vq import train_codebook

    w = stage.importance
    w = w / w.max() if w.max() > 0 else np.ones_like(w)
    kw = {} if iters is None else {"iters": int(iters)}
    bar = progress.bar(1, "vq") if progress is not None else None
    return train_codebook(stage.sh, w, min(int(size), stage.num_points), seed=seed, progress=bar, **kw)


def sh_chunk(stage: Stage, codebook: np.ndarray, keep: int, sh_bits: int, blocks: int):
    """SHVQ chunk payload, the SH the decoder will reconstruct ([M, K, 3] float32), and stats.

    The ``keep`` most important Gaussians keep their exact vectors (quantised at sh_bits like
    the codebook); every other Gaussian takes its nearest codeword."""
    from .rans import encode_stream
    from .vq import assign, compact

    m, d = stage.sh.shape
    keep = min(int(keep), m)
    kept = _top_k_mask(stage.importance, keep)
    rest = ~kept
    if rest.any():
        cb, idx = compact(codebook, assign(stage.sh[rest], codebook))
    else:
        cb, idx = np.zeros((1, d), np.float32), np.zeros(0, np.int32)
    w = Writer()
    w.u32(cb.shape[0]).u32(keep).u16(d)
    cb_bytes, cb_rec = write_channel_set(cb.T, sh_bits, blocks)
    w.bytes(cb_bytes)
    out = np.empty((m, d), np.float32)
    stats = {"kept": keep, "codebook_size": int(cb.shape[0]), "codebook_bytes": len(cb_bytes)}
    if keep:
        kept_bytes, kept_rec = write_channel_set(stage.sh[kept].T, sh_bits, blocks)
        w.bytes(kept_bytes)
        flags = encode_stream(kept.astype(np.int64), np.zeros(m, np.int64), 1)
        w.blob(flags)
        out[kept] = kept_rec.T
        stats["kept_bytes"] = len(kept_bytes) + len(flags) + 8
    idx_blob = encode_stream(idx.astype(np.int64), np.zeros(idx.size, np.int64), 1)
    w.blob(idx_blob)
    out[rest] = cb_rec.T[idx]
    stats["index_bytes"] = len(idx_blob) + 8
    k = m and d // 3
    return w.getvalue(), out.reshape(m, k, 3), stats


def assemble(stage: Stage, attr: bytes, decoded, sh: bytes | None, sh_rest, meta: dict):
    """The .gsz bytes and the cloud the decoder will reconstruct."""
    import zstandard
    from gsz.decoder.geometry import voxel_centres

    vox = stage.vox
    m = stage.num_points
    out_cloud = GaussianCloud(
        positions=voxel_centres(vox.ijk, vox.origin, vox.side, stage.depth).astype(np.float32),
        scales=decoded.scales, rotations=decoded.rotations, opacities=decoded.opacities,
        sh_dc=decoded.sh_dc, sh_rest=sh_rest if sh is not None else np.zeros((m, 0, 3), np.float32),
        sh_degree=stage.sh_degree)
    chunks = [Chunk(CHUNK_GEOM, stage.geometry, CHUNK_REQUIRED), Chunk(CHUNK_ATTR, attr, CHUNK_REQUIRED)]
    if sh is not None:
        chunks.append(Chunk(CHUNK_SHVQ, sh, CHUNK_REQUIRED))
    meta_bytes = zstandard.ZstdCompressor(level=19).compress(
        json.dumps(meta, sort_keys=True, separators=(",", ":"), default=float).encode())
    chunks.append(Chunk(CHUNK_META, meta_bytes, 0))
    header = FileHeader(num_gaussians=m, sh_degree=stage.sh_degree, frame=FRAME_RDF,
                        bbox_min=tuple(out_cloud.positions.min(0)),
                        bbox_max=tuple(out_cloud.positions.max(0)))
    return write_container(header, chunks), out_cloud, len(meta_bytes)


def compute_train_importance(cloud: GaussianCloud, opts: EncodeOptions, *, cameras=None,
                             progress: Progress | None = None) -> np.ndarray:
    """Importance I = I_d * (V/V_ref)^beta over the train views (default camera set if None)."""
    from .cameras import load_cameras
    from .importance import compute_importance

    progress = progress or Progress(quiet=True)
    if cameras is None:
        cameras = load_cameras(None, cloud, n_train=opts.train_views, n_test=8,
                               width=opts.importance_width).train
    else:
        cameras = [c.scaled(opts.importance_width) if c.width > opts.importance_width else c
                   for c in cameras]
    with progress.stage("importance", f"{len(cameras)} views at {cameras[0].width}x{cameras[0].height}"):
        return compute_importance(cloud, cameras, beta=opts.beta,
                                  progress=progress.bar(len(cameras), "importance"))


def encode(cloud: GaussianCloud, options: EncodeOptions | None = None, *, cameras=None,
           importance: np.ndarray | None = None, progress: Progress | None = None) -> EncodeResult:
    """Compress ``cloud`` with ``options``; ``cameras`` are the train views for importance
    (default: the deterministic default camera set).  ``importance`` [N] skips the importance
    pass when the caller already has it (e.g. several encodes of one scene).  Returns the .gsz
    bytes, the cloud the decoder will reconstruct, and a report (sizes per component, seconds
    per stage)."""
    opts = (options or EncodeOptions()).validate()
    progress = progress or Progress(quiet=True)
    cloud.validate()
    n_in = len(cloud)
    t_start = time.perf_counter()
    if importance is None:
        importance = compute_train_importance(cloud, opts, cameras=cameras, progress=progress)
    else:
        importance = np.asarray(importance, np.float64)
        if importance.shape != (n_in,) or not np.all(np.isfinite(importance)):
            raise EncodeOptionsError(f"importance must be {n_in} finite values")
    stage = prepare_stage(cloud, importance, opts.reserve, depth=opts.depth,
                          rel_error=opts.rel_error, progress=progress)
    m = stage.num_points
    with progress.stage("attributes", f"{opts.bits} bits, {opts.blocks} blocks"):
        attr, decoded, attr_stats = attribute_chunk(stage, opts.bits, opts.bits, opts.blocks)
    sh = sh_rest = None
    sh_stats = {}
    if cloud.sh_degree > 0:
        k = default_codebook_size(m, opts.codebook)
        with progress.stage("sh", f"codebook {k}"):
            cb = train_sh_codebook(stage, k, seed=opts.seed, iters=opts.vq_iters, progress=progress)
            keep = int(round(0.01 * m)) if opts.keep is None else int(opts.keep)
            sh, sh_rest, sh_stats = sh_chunk(stage, cb, keep, int(opts.sh_bits or opts.bits), opts.blocks)
    options_json = dict(asdict(opts), depth=stage.depth)
    with progress.stage("container"):
        meta = {"encoder": "gsz 0.1.0", "codec": "mesongs++", "options": options_json,
                "input_gaussians": n_in, "voxels": m}
        data, out_cloud, meta_len = assemble(stage, attr, decoded, sh, sh_rest, meta)
    sizes = {"geometry": len(stage.geometry), "attributes": len(attr), **attr_stats,
             "metadata": meta_len}
    if sh is not None:
        sizes["sh"] = len(sh)
        sizes.update({f"sh_{k}": v for k, v in sh_stats.items() if k.endswith("bytes")})
    sizes["container_overhead"] = len(data) - sum(sizes[k] for k in ("geometry", "attributes", "metadata")) \
        - sizes.get("sh", 0)
    report = {
        "bytes": len(data), "input_gaussians": n_in, "kept_after_prune": len(stage.vox.index_of_point),
        "voxels": m, "bytes_per_gaussian": len(data) / m, "depth": stage.depth,
        "merged_fraction": stage.vox.merged_fraction, "sh_degree": cloud.sh_degree, "components": sizes,
        "sh": {k: v for k, v in sh_stats.items() if not k.endswith("bytes")},
        "seconds": dict(progress.seconds), "total_seconds": time.perf_counter() - t_start,
        "options": options_json,
    }
    return EncodeResult(data=data, cloud=out_cloud, report=report)
