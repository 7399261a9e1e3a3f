"""The MesonGS++ encode pipeline at an explicit configuration.

    encode(cloud, EncodeOptions(reserve=0.8, bits=12)) -> EncodeResult(data=b"...", report=EncodeReport)

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

import dataclasses
import functools
import json
import time
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from ..decoder.bytesio import Writer
from ..decoder.cloud import FRESH, GaussianCloud, MadeRows, OutputRows
from ..decoder.container import (CHUNK_ENTRY_SIZE, CHUNK_REQUIRED, FRAME_RDF, LAYER_SHIFT, Chunk, FileHeader,
                                 write_container)
from ..decoder.errors import GszUsageError
from ..decoder.layout import (CHUNK_ATTR, CHUNK_GEOM, CHUNK_META, CHUNK_RWGT, CHUNK_SHCL, CHUNK_SHRF, CHUNK_SHVQ,
                              CHUNK_SHXF, RAHT_CHANNELS, ROTATION_EULER_ZYX)
from ..decoder.morton import morton_encode
from ..decoder.raht import build_raht_tree
from ..decoder.rotation import quaternion_to_euler
from ..decoder.sh import (MAX_CODEBOOK, MAX_SH_CLASSES, SH_CLASSES_FROM_RWGT, SH_COLOUR_DC, SH_COLOUR_KLT,
                          ShColour, class_order, luma_chroma_to_rgb)
from ..decoder.threads import for_ranges, thread_map
from ..evaluation.cameras import DEFAULT_VIEW_WIDTH

from .encode_report import MODE_FIXED, EncodeReport, FixedDetails
from .executor import in_order
from .geometry import write_geometry
from .groups import QUANT_CHANNELS, write_channel_set
from .importance import prune, top_k_mask
from .progress import Progress
from .sh_colour import SH_COLOUR_CHOICES, choose_sh_colour, coded_cloud, decoded_sh_rest, sh_colour_name
from .voxelize import SourcedRows  # noqa: F401  (a Stage's SH rows; re-exported)


class EncodeOptionsError(GszUsageError):
    """An encoder option is out of range."""


#: Default layer count (1: a single-layer file has the best fidelity per byte), the layer count
#: of ``gsz-encode --layers`` without a number, and the layer-0 share (docs/design/layers.md).
DEFAULT_LAYERS = 1
STREAMING_LAYERS = 3
DEFAULT_FIRST_LAYER = 0.1
MAX_LAYERS = 16

#: blocks per channel of the fixed configuration below ONE_BLOCK_MIN_BITS (and of the search)
MANY_BLOCKS = 80
#: uniform bit-width from which the fixed configuration's default is one block per channel
ONE_BLOCK_MIN_BITS = 10


def default_blocks(bits: int) -> int:
    """Blocks per channel of a fixed configuration at a uniform ``bits`` (no --blocks given).

    One block gives one quantisation step per channel over all of its RAHT coefficients --
    equal steps, what minimises the error of an orthonormal transform at a given rate when the
    steps are fine; per-block min/max at the same width spends levels on blocks of tiny
    fine-level coefficients.  When the steps are coarse the coarsest coefficients (which set a
    single block's range) make the step too big for the fine ones and colour detail rounds
    away, so below ONE_BLOCK_MIN_BITS blocks win (docs/design/default-blocks.md)."""
    return 1 if int(bits) >= ONE_BLOCK_MIN_BITS else MANY_BLOCKS


def check_layer_options(layers, first_layer, bad) -> None:
    if not (1 <= int(layers) <= MAX_LAYERS):
        bad(f"--layers must be 1..{MAX_LAYERS}, got {layers}")
    if not (0.0 < float(first_layer) < 1.0):
        bad(f"--first-layer must be in (0, 1), got {first_layer}")


#: Voxels per spatial tile from which a scene is split (``--tile-gaussians``; see split_tiles):
#: scenes up to it stay one tile.
DEFAULT_TILE_GAUSSIANS = 1 << 20
#: Importance classes of the RAHT leaves (``--raht-classes``, an RWGT chunk per part; 1: none)
#: and the fewest voxels per class a part needs for them (below, the chunk costs more than the
#: weighting gives).
DEFAULT_RAHT_CLASSES = 8
MAX_RAHT_CLASSES = 16
RAHT_CLASS_MIN_SIZE = 64
#: ... and the least spread of the weights (their arithmetic over geometric mean across the
#: voxels) worth the classes' log2(Q) bits a voxel: at high rate the weighting saves about
#: 0.5 log2(AM/GM) bits per coefficient of each of 7 channels, so below ~1.5 it cannot pay
RAHT_CLASS_MIN_SPREAD = 1.5
#: ... and, in the size search, the fewest budget bits per voxel: below 5 bytes a voxel the
#: classes' 3 bits take more than ~7 % of the file, and measured searches lost up to 0.6 dB
#: (docs/design/raht-weights.md)
RAHT_CLASS_MIN_BUDGET_BITS = 40


def raht_classes_for(requested: int, target_bytes: int, voxels: int) -> int:
    """The RAHT classes a size-search stage of ``voxels`` uses under ``target_bytes``: the
    requested count, or 1 (plain RAHT) where the budget is too small for them to pay."""
    return int(requested) if 8 * int(target_bytes) >= RAHT_CLASS_MIN_BUDGET_BITS * int(voxels) else 1


#: the smallest tile (``--tile-gaussians``): below it the per-tile octree top levels, codebook
#: and group metadata cost more than tiling gives
MIN_TILE_GAUSSIANS = 4096


def encoder_name() -> str:
    """What META's "encoder" field records: "gsz <version>"."""
    from .. import __version__
    return f"gsz {__version__}"


def check_tile_option(tile_gaussians, bad) -> None:
    if tile_gaussians is not None and int(tile_gaussians) < MIN_TILE_GAUSSIANS:
        bad(f"--tile-gaussians must be >= {MIN_TILE_GAUSSIANS} (or 0 for no tiles), got {tile_gaussians}")


def layer_sizes(m: int, layers: int, first_layer: float) -> list[int]:
    """Gaussians per layer: the cumulative share of layers 0..l is
    ``first_layer ** ((L - 1 - l) / (L - 1))`` (10 %, 32 %, 100 % for L = 3), so every layer
    roughly multiplies the scene's Gaussians by the same factor.  Every layer gets at least one
    Gaussian (fewer layers when m < L)."""
    layers = max(1, min(int(layers), int(m)))
    if layers == 1:
        return [int(m)]
    cum = [int(round(m * float(first_layer) ** ((layers - 1 - l) / (layers - 1)))) for l in range(layers)]
    cum[-1] = int(m)
    sizes, prev = [], 0
    for l, c in enumerate(cum):
        c = max(c, prev + 1)
        c = min(c, int(m) - (layers - 1 - l))
        sizes.append(c - prev)
        prev = c
    return sizes


@dataclass(kw_only=True)
class SceneOptions:
    """The knobs a fixed configuration (:class:`EncodeOptions`) and the size search
    (``SearchOptions``) share -- one home for each.

    beta             exponent of the volume term of the importance
    train_views      number of default train cameras (when no camera file is given)
    importance_width render width of the importance pass (wider cameras are downscaled to
                     it); the default is the width scenes are evaluated and viewed at
                     (DEFAULT_VIEW_WIDTH): below it small Gaussians hide under a pixel and
                     pruning removes detail that shows at 800 px (docs/design/view-width.md)
    vq_iters         mini-batch k-means iterations (None: the codebook trainer's default)
    layers           importance-ordered layers (1 = a single-layer file); layer 0 holds the
                     most important Gaussians and decodes on its own (progressive streaming);
                     the search's bit allocation runs over the groups of every layer at once
    first_layer      fraction of the Gaussians in layer 0 when layers > 1 (later layers grow
                     geometrically, see :func:`layer_sizes`)
    tile_gaussians   split a scene of more voxels into spatial tiles of at most this many, each
                     decodable alone (format 1.2); None: never split.  The search's one bit
                     allocation spans every tile's groups, so the budget holds for the file
    raht_classes     importance classes of the RAHT leaves (2..16: an RWGT chunk per part,
                     format 1.5, whose class weights make the transform's coefficient errors
                     importance-weighted, so important Gaussians get finer attributes at the
                     same bytes; 1: plain RAHT) -- docs/design/raht-weights.md
    executor         where per-tile work runs: "local" worker processes, "inline", "ray" or
                     "ray://HOST:PORT" (:mod:`gsz.encoder.executor`); the bytes do not depend on it
    workers          worker processes / local Ray CPUs (None: the machine's cores less one)
    sh_colour        colour space of the SH rest and DC colour: "luma-chroma" (an SHXF chunk
                     per part, format 1.7: correlated channels code in fewer bits), "klt" (the
                     SH rest in its own principal axes, format 1.8: correlated coefficients
                     too), "rgb", or "auto": the DC as luma/chroma, the SH rest in the KLT
                     where it gains, else luma/chroma unless it sits on a delivery format's
                     coarse grid (:mod:`gsz.encoder.sh_colour`, docs/design/sh-colour.md,
                     sh-klt.md)
    seed             RNG seed (VQ); the same input and options give byte-identical output
    """

    beta: float = 0.1
    train_views: int = 24
    importance_width: int = DEFAULT_VIEW_WIDTH
    vq_iters: int | None = None
    layers: int = DEFAULT_LAYERS
    first_layer: float = DEFAULT_FIRST_LAYER
    tile_gaussians: int | None = DEFAULT_TILE_GAUSSIANS
    raht_classes: int = DEFAULT_RAHT_CLASSES
    executor: str = "local"
    workers: int | None = None
    sh_colour: str = "auto"
    seed: int = 0

    def check_scene_options(self, bad) -> None:
        """``bad(message)`` (which raises) on the first shared option out of range."""
        if not (float(self.beta) >= 0):
            bad(f"--beta must be >= 0, got {self.beta}")
        if int(self.train_views) < 1:
            bad(f"--train-views must be >= 1, got {self.train_views}")
        if int(self.importance_width) < 16:
            bad(f"--importance-width must be >= 16, got {self.importance_width}")
        check_layer_options(self.layers, self.first_layer, bad)
        check_tile_option(self.tile_gaussians, bad)
        if not (1 <= int(self.raht_classes) <= MAX_RAHT_CLASSES):
            bad(f"--raht-classes must be 1..{MAX_RAHT_CLASSES}, got {self.raht_classes}")
        if self.sh_colour not in SH_COLOUR_CHOICES:
            bad(f"--sh-colour must be one of {', '.join(SH_COLOUR_CHOICES)}, got {self.sh_colour!r}")
        from .executor import check_executor
        check_executor(self.executor, self.workers, bad)

    def scene_options(self) -> dict:
        """The shared fields and their values (to build the other kind of options from)."""
        return {f.name: getattr(self, f.name) for f in fields(SceneOptions)}


@dataclass(kw_only=True)
class EncodeOptions(SceneOptions):
    """Every knob of the codec at a fixed configuration (the size search chooses them later);
    the fields shared with the search are :class:`SceneOptions`'.

    reserve          tau: fraction of Gaussians kept after importance pruning, (0, 1]
    bits             uniform bit-width of every quantisation group, 1..16
    codebook         SH VQ codebook size K (1..65536); capped at one codeword per 8 Gaussians
    keep             number of most important Gaussians whose exact SH vectors are kept
                     (None: 1 % of the voxels)
    blocks           blocks per quantised channel (groups = channels x blocks); None: the
                     default of :func:`default_blocks` for the bit-width of each channel set
                     (1 block from ONE_BLOCK_MIN_BITS bits up, MANY_BLOCKS below)
    depth            octree depth 1..21 (None: chosen from the position-error budget)
    rel_error        position-error budget relative to the robust scene diagonal (auto depth)
    sh_bits          bit-width of SH codebook / kept vectors (None: same as ``bits``)
    sh_classes       importance classes of the kept SH vectors (2..16: an SHCL chunk, format
                     1.3, and one block per class; 1: none).  At one fixed width they only
                     order the vectors; the size search gives each class its own widths
    sh_refine        the kept SH vectors as residuals of their nearest codeword (an SHRF chunk,
                     format 1.9): every vector takes a codeword, the kept ones a correction
    """

    reserve: float = 0.8
    bits: int = 12
    codebook: int = 4096
    keep: int | None = None
    blocks: int | None = None
    depth: int | None = None
    rel_error: float | None = None
    sh_bits: int | None = None
    sh_classes: int = 1
    sh_refine: bool = False

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
        if self.blocks is not None and not (1 <= int(self.blocks) <= 65535):
            bad(f"--blocks must be 1..65535, got {self.blocks}")
        if self.depth is not None and not (1 <= int(self.depth) <= 21):
            bad(f"--depth must be 1..21, got {self.depth}")
        if self.rel_error is not None and not (float(self.rel_error) > 0):
            bad(f"--rel-error must be > 0, got {self.rel_error}")
        if not (1 <= int(self.sh_classes) <= MAX_SH_CLASSES):
            bad(f"--sh-classes must be 1..{MAX_SH_CLASSES}, got {self.sh_classes}")
        self.check_scene_options(bad)
        return self


class EncodeResult:
    """The .gsz bytes (``data``), what the decoder will reconstruct from them (``cloud``, for
    reports / evaluation) and the ``report`` (sizes, choices and costs; the same shape for both
    modes).  Given no cloud, it is decoded from the bytes when first asked for: the size search
    keeps none, and a 6 M-Gaussian decode at its end (2-3 GB with its transients) was the largest
    peak of a gsz-encode that only writes the file."""

    def __init__(self, data: bytes, cloud: GaussianCloud | None = None, report: EncodeReport | None = None):
        self.data, self._cloud, self.report = data, cloud, report

    @property
    def cloud(self) -> GaussianCloud:
        if self._cloud is None:
            from ..decoder import decode
            self._cloud = decode(self.data)
        return self._cloud

    def __repr__(self) -> str:
        return f"EncodeResult({len(self.data):,} bytes)"


@dataclass
class Layer:
    """One importance layer: a subset of the stage's voxels coded as a scene of its own (octree,
    RAHT tree, channel sets) on the stage's voxel grid; the SH codebook is shared.

    index      [M_l] int64 ascending indices into the stage's voxels (so Morton order)
    geometry_job  GEOM chunk payload of the layer, or a Future of it while a worker thread codes
                  it (read :attr:`geometry`)
    raht_dc    [7] float64 RAHT root coefficients (stored exactly)
    raht_weights  RahtWeights of the part's RWGT chunk (importance classes of its voxels and
               their leaf weights), or None: plain RAHT
    raht_ac    [7, M_l-1] float32 AC coefficients in stream (level) order
    scales     [3, M_l] float32 log-scales in Morton order, or in class order (``scale_order``)
               in a part with RAHT weights
    codes      [M_l] uint64 Morton codes of the layer's voxels on its grid (what a decoder
               rebuilds the RAHT tree from)
    layer, tile   which part of the file this is (a file without tiles has only tile 0)
    grid       (origin [3] float64, side, depth) of the part's GEOM: the stage's grid, or in a
               tiled file the tile's own cube on the same voxel pitch
    """

    index: np.ndarray
    geometry_job: object
    raht_dc: np.ndarray
    raht_ac: np.ndarray
    scales: np.ndarray
    codes: np.ndarray
    layer: int = 0
    tile: int = 0
    grid: tuple | None = None
    raht_weights: object = None

    @property
    def leaf_weights(self):
        """int64 [M_l] RAHT leaf weights of the part's RWGT chunk, or None (plain RAHT)."""
        return None if self.raht_weights is None else self.raht_weights.leaf_weights

    @property
    def scale_order(self):
        """int64 [M_l] the voxel (of the part) of each column of ``scales`` when they are stored
        in class order (a part with RAHT weights, GSZ.md §7.1), else None (Morton order)."""
        return None if self.raht_weights is None else self.raht_weights.order

    @functools.cached_property
    def weights_chunk(self) -> bytes | None:
        """The part's RWGT chunk payload (GSZ.md §7.1), or None (coded once: the search sizes
        every candidate's fixed bytes with it)."""
        return None if self.raht_weights is None else raht_weights_chunk(self.raht_weights)

    @property
    def side_bytes(self) -> int:
        """Bytes the part's GEOM and RWGT chunks take beside the channel sets (RWGT's table
        entry included): fixed once the stage is made."""
        w = self.weights_chunk
        return len(self.geometry) + (0 if w is None else len(w) + CHUNK_ENTRY_SIZE)

    @property
    def geometry(self) -> bytes:
        """GEOM chunk payload of the layer (waits for the worker thread coding it, if any)."""
        if not isinstance(self.geometry_job, bytes):
            self.geometry_job = self.geometry_job.result()
        return self.geometry_job

    @property
    def num_points(self) -> int:
        return len(self.index)

    @property
    def depth(self) -> int:
        """Octree depth of the part's grid (its RAHT tree's)."""
        return self.grid[2]


@dataclass
class Stage:
    """Everything that depends on the reserve ratio, depth and layering but not on bit-widths.
    It keeps only what coding needs of the voxel grid it was made from (the grid's other fields
    and its coordinates are 100 bytes a voxel; the parts' Morton codes give the positions).

    layers     [Layer], importance order (layer 0 = most important voxels)
    sh         [M, D] float32 higher-degree SH vectors in voxel order (D = 0 for SH degree 0): a
               :class:`SourcedRows` on the input cloud's (index it, as an array's rows)
    importance [M] float64 merged importance in voxel order
    kept       Gaussians kept by pruning (before merging into M voxels)
    source     [M] int64 index into the input cloud of the one Gaussian a voxel holds, -1 where
               several were merged (lets the size search reuse per-Gaussian work across taus)
    sh_colour  the SHXF transform bits ``sh`` and the DC are coded in (gsz.decoder.sh; 0: RGB,
               no chunk): the cloud the stage was made from already holds them in that space
    executor   where the per-tile work of a tiled stage runs (:mod:`gsz.encoder.executor`;
               None: here)
    cache      scratch for work that depends on the stage only (the size search's tables)
    """

    reserve: float
    depth: int
    layers: list
    sh: SourcedRows
    importance: np.ndarray
    sh_degree: int
    input_gaussians: int
    kept: int
    source: np.ndarray | None = None
    sh_colour: int = 0
    executor: object = field(default=None, repr=False, compare=False)
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def num_points(self) -> int:
        return len(self.importance)

    @property
    def merged_fraction(self) -> float:
        """Share of the kept Gaussians merged away (as Voxelized.merged_fraction)."""
        return 1.0 - self.num_points / self.kept

    @property
    def geometry_bytes(self) -> int:
        """GEOM payloads and RWGT chunks (their entries included) of every part."""
        return sum(l.side_bytes for l in self.layers)

    @property
    def num_tiles(self) -> int:
        return 1 + max(l.tile for l in self.layers)

    @property
    def layer0_points(self) -> int:
        """Gaussians in layer 0 (of every tile): what a streaming reader shows first."""
        return sum(l.num_points for l in self.layers if l.layer == 0)

    def positions(self) -> np.ndarray:
        """float32 [M, 3] decoded positions in output order (each part on its own grid)."""
        from ..decoder.geometry import centres_float32
        from ..decoder.morton import morton_decode_planes
        out = np.empty((self.num_points, 3), np.float32)
        end = 0
        for l in self.layers:                   # each part straight into its rows
            centres_float32(morton_decode_planes(l.codes), *l.grid, out=out[end:end + l.num_points])
            end += l.num_points
        return out

    @property
    def order(self) -> np.ndarray:
        """Voxel index of every decoded Gaussian (decoders emit layer after layer)."""
        return np.concatenate([l.index for l in self.layers])

    def layer_blocks(self, blocks: int) -> list[int]:
        """Blocks per channel in each layer: ``blocks`` spread over the layers by their share of
        the Gaussians, so a layered file has about as many groups (and as much group metadata)
        as a single-layer one."""
        return scaled_blocks(blocks, [l.num_points for l in self.layers])


def scaled_blocks(blocks: int, counts: list[int]) -> list[int]:
    total = max(1, sum(counts))
    if len(counts) == 1:
        return [int(blocks)]
    return [max(1, min(65535, int(round(blocks * c / total)))) for c in counts]


def split_layers(importance: np.ndarray, layers: int, first_layer: float) -> np.ndarray:
    """Layer index [M] of every voxel: the most important ``layer_sizes[0]`` go to layer 0, the
    next ones to layer 1, ... (ties broken by lower index, deterministic)."""
    m = importance.shape[0]
    sizes = layer_sizes(m, layers, first_layer)
    rank = np.lexsort((np.arange(m), -importance))
    out = np.empty(m, np.int64)
    out[rank] = np.repeat(np.arange(len(sizes)), sizes)
    return out


def split_tiles(codes: np.ndarray, depth: int, limit: int | None) -> list:
    """Spatial tiles of voxels with ascending Morton ``codes``: [(start, stop)] ranges of at
    most ``limit`` voxels, each a run of whole octree cells (children of one cell merged while
    they fit, a cell above the limit split into its children), so every tile is a compact block
    of the scene.  One tile when the scene fits or ``limit`` is None."""
    m = int(codes.shape[0])
    if limit is None or m <= int(limit):
        return [(0, m)]
    limit = int(limit)
    tiles = []

    def cell(lo: int, hi: int, level: int) -> None:
        if hi - lo <= limit or level >= depth:
            tiles.append((lo, hi))
            return
        shift = np.uint64(3 * (depth - level - 1))
        child = (codes[lo:hi] >> shift) & np.uint64(7)
        cuts = lo + np.searchsorted(child, np.arange(9, dtype=np.uint64))
        run = None
        for c in range(8):
            a, b = int(cuts[c]), int(cuts[c + 1])
            if a == b:
                continue
            if b - a > limit:
                if run is not None:
                    tiles.append(run)
                    run = None
                cell(a, b, level + 1)
            elif run is not None and b - run[0] <= limit:
                run = (run[0], b)
            else:
                if run is not None:
                    tiles.append(run)
                run = (a, b)
        if run is not None:
            tiles.append(run)

    cell(0, m, 0)
    return tiles


def part_ijk(vox, idx: np.ndarray, grid: tuple) -> np.ndarray:
    """[M_l, 3] coordinates of the voxels ``idx`` on ``grid`` (a tile's cube has the stage's
    pitch, so they are the stage's coordinates shifted by the cube's corner)."""
    if grid[2] == vox.depth and grid[1] == vox.side:
        return vox.ijk[idx]
    shift = np.rint((np.asarray(grid[0]) - np.asarray(vox.origin, np.float64))
                    * (1 << vox.depth) / vox.side).astype(np.int64)
    return vox.ijk[idx] - shift


def tile_grid(codes: np.ndarray, ijk: np.ndarray, origin, side: float, depth: int):
    """(origin, side, depth) of a tile's GEOM: the smallest octree cell of the stage's grid that
    holds the tile's voxels (Morton ``codes`` ascending, coordinates ``ijk``).  Aligned to the
    stage's octree, so the voxels keep their Morton order on the tile's own grid."""
    diff = int(codes[0]) ^ int(codes[-1])
    d = max(1, -(-diff.bit_length() // 3))
    corner = (ijk[0] >> d) << d
    pitch = float(side) / float(1 << int(depth))
    return (np.asarray(origin, np.float64) + corner.astype(np.float64) * pitch, pitch * float(1 << d), d)


def voxelize_stage(cloud: GaussianCloud, importance: np.ndarray, reserve: float, *, depth=None,
                   rel_error=None, progress: Progress | None = None):
    """Prune to ``reserve`` and voxelise: (kept input indices [K], Voxelized, its SH rest as rows
    of the input's).  ``vox.full_cloud()`` (voxel centres, merged attributes) is what a decoder
    would reconstruct with every attribute exact, so its fidelity bounds what any bit
    allocation at this reserve and depth reaches."""
    from .voxelize import DEFAULT_REL_ERROR, choose_depth, voxelize

    progress = progress or Progress(quiet=True)
    with progress.stage("prune", f"reserve {reserve}"):
        kept = prune(importance, reserve)
        imp = importance[kept]
    with progress.stage("voxelize"):
        rel = DEFAULT_REL_ERROR if rel_error is None else float(rel_error)
        d = int(depth) if depth is not None else choose_depth(cloud.positions[kept], rel_error=rel)
        # no pruned copy of the cloud, and the voxels' SH as rows of the input's
        vox = voxelize(cloud, imp, d, rows=kept, sourced_sh=True)
        pruned = len(kept)
        progress.log(f"depth {d}: {pruned} Gaussians -> {len(vox.ijk)} voxels "
                     f"({100 * vox.merged_fraction:.2f} % merged"
                     + (f", {vox.relocated} moved to a neighbouring voxel)" if vox.relocated else ")"))
    return kept, vox


def stage_source(kept: np.ndarray, vox) -> np.ndarray:
    """Stage.source: per voxel the input index of its one Gaussian, -1 where several merged."""
    m = len(vox.ijk)
    members = np.bincount(vox.index_of_point, minlength=m)
    source = np.full(m, -1, np.int64)
    source[vox.index_of_point] = kept
    source[members != 1] = -1
    return source


def prepare_stage(cloud: GaussianCloud, importance: np.ndarray, reserve: float, *, depth=None,
                  rel_error=None, layers: int = DEFAULT_LAYERS, first_layer: float = DEFAULT_FIRST_LAYER,
                  progress: Progress | None = None, voxelized=None, pool=None,
                  tile_gaussians: int | None = None, executor=None,
                  raht_classes: int = DEFAULT_RAHT_CLASSES, sh_colour: int = 0) -> Stage:
    """Prune to ``reserve``, voxelise, split into spatial tiles of at most ``tile_gaussians``
    voxels (None: one tile) and each tile into importance layers, code each part's geometry
    and transform its attributes (a tiled stage's parts on ``executor`` when given, which also
    codes their attributes later).  ``voxelized``: the (kept, Voxelized) of
    :func:`voxelize_stage` for these arguments when the caller already has it.  ``pool``: an
    executor that codes the geometry while the caller goes on (the octree coder runs without
    the GIL; nothing before the file size needs its bytes).  ``sh_colour``: the SHXF transform bits
    ``cloud``'s SH rest and DC are already in (:func:`gsz.encoder.sh_colour.coded_cloud`)."""
    progress = progress or Progress(quiet=True)
    if voxelized is None:
        voxelized = voxelize_stage(cloud, importance, reserve, depth=depth, rel_error=rel_error,
                                   progress=progress)
    kept, vox = voxelized
    d = vox.depth
    source = stage_source(kept, vox) if vox.sh is None else vox.sh.source
    codes = morton_encode(vox.ijk)
    tiles = split_tiles(codes, d, tile_gaussians)
    part_of = []                    # (layer, tile, voxel indices)
    for t, (lo, hi) in enumerate(tiles):
        layer_of = split_layers(vox.importance[lo:hi], layers, first_layer)
        for li in range(int(layer_of.max()) + 1):
            part_of.append((li, t, lo + np.flatnonzero(layer_of == li)))
    part_of.sort(key=lambda p: (p[0], p[1]))
    grids = [(vox.origin, vox.side, d)] if len(tiles) == 1 else \
        [tile_grid(codes[lo:hi], vox.ijk[lo:hi], vox.origin, vox.side, d) for lo, hi in tiles]
    parts = _prepare_parts(vox, part_of, grids, layers, progress, pool, executor, raht_classes)
    sh = SourcedRows.of_grid(cloud.sh_rest.reshape(len(cloud), -1), source, vox)
    return Stage(reserve=float(reserve), depth=d, layers=parts, sh=sh, importance=vox.importance,
                 sh_degree=cloud.sh_degree, input_gaussians=len(cloud), kept=len(kept), source=source,
                 sh_colour=sh_colour if cloud.sh_degree else ShColour(int(sh_colour) & SH_COLOUR_DC),
                 executor=executor)


#: importance above this quantile counts as the quantile's value in class and block weights:
#: one huge Gaussian (an outlier the sanitiser clamped, still covering the scene) would
#: otherwise lift the top class's mean and the stage's and coarsen every other Gaussian
IMPORTANCE_CAP_QUANTILE = 0.999


def capped_importance(importance: np.ndarray) -> np.ndarray:
    """``importance`` with values above its IMPORTANCE_CAP_QUANTILE set to that quantile."""
    if importance.size == 0:
        return importance
    return np.minimum(importance, np.quantile(importance, IMPORTANCE_CAP_QUANTILE))


def raht_weights(importance: np.ndarray, q: int):
    """The RWGT chunk's content for a part's voxels (their ``importance``, Morton order): ``q``
    equal runs by importance (importance_classes), each class weighted by its mean importance,
    the top class 65535 (integer weights keep the tree's sums exact); None when the weights
    would differ too little or the part is too small for them (TRANSFORMS.md §2.5)."""
    from ..decoder.attributes import RahtWeights
    from ..decoder.raht import MAX_LEAF_WEIGHT
    m = importance.shape[0]
    if q < 2 or m < RAHT_CLASS_MIN_SIZE * q:
        return None
    classes = importance_classes(importance, q)
    capped = capped_importance(importance)
    means = (np.bincount(classes, weights=capped, minlength=q)
             / np.maximum(np.bincount(classes, minlength=q), 1))
    top = float(means.max())
    if not top > 0:
        return None
    w = np.clip(np.rint(MAX_LEAF_WEIGHT * means / top), 1, MAX_LEAF_WEIGHT).astype(np.int64)
    leaf = w[classes].astype(np.float64)
    if leaf.mean() < RAHT_CLASS_MIN_SPREAD * np.exp(np.log(leaf).mean()):
        return None
    return RahtWeights(classes=classes, weights=w)


def raht_weights_chunk(rw) -> bytes:
    """RWGT payload: u8 Q, u16 weights[Q], the classes as one rANS stream."""
    from .rans import encode_stream
    q = rw.weights.shape[0]
    return (Writer().u8(q).array(rw.weights, np.dtype("<u2"))
            .blob(encode_stream(rw.classes, np.zeros(rw.classes.shape[0], np.int64), 1)).getvalue())


def _transform(ijk: np.ndarray, depth: int, rotations, opacities, sh_dc, weights=None):
    """Morton codes, RAHT DC [7] and AC [7, M-1] (float32) of one part's voxels over its tree,
    weighted by ``weights`` (RahtWeights) when given (the tree goes: 40 bytes a voxel, and the
    codes rebuild it where the NumPy decode path needs it)."""
    from .raht import raht_forward
    codes = morton_encode(ijk)
    tree = build_raht_tree(codes, depth, None if weights is None else weights.leaf_weights)
    euler = quaternion_to_euler(rotations.astype(np.float64))
    attrs = np.concatenate([opacities.astype(np.float64)[:, None], euler, sh_dc.astype(np.float64)], axis=1)
    dc, ac = raht_forward(attrs, tree)
    return codes, dc, np.ascontiguousarray(ac.T, dtype=np.float32)


@dataclass
class PartJob:
    """Everything coding one part's geometry and transform needs (sent to a worker)."""
    ijk: np.ndarray
    grid: tuple
    rotations: np.ndarray
    opacities: np.ndarray
    sh_dc: np.ndarray
    weights: object = None


def code_part(job: PartJob):
    """(GEOM payload, codes, RAHT DC, RAHT AC) of one part: the executor's unit of work."""
    origin, side, depth = job.grid
    geometry = write_geometry(job.ijk, origin, side, depth)
    return (geometry,) + _transform(job.ijk, depth, job.rotations, job.opacities, job.sh_dc, job.weights)


def _part_job(vox, idx: np.ndarray, grid: tuple, weights) -> PartJob:
    c = vox.cloud
    return PartJob(part_ijk(vox, idx, grid), grid, c.rotations[idx], c.opacities[idx], c.sh_dc[idx], weights)


def _part_tag(li: int, t: int, n: int, tiles: int, layers: int) -> str:
    tag = ", ".join(([f"layer {li}"] if layers > 1 else []) + ([f"tile {t}"] if tiles > 1 else []))
    return f"{tag}, {n} voxels" if tag else ""


def _prepare_part(vox, li: int, t: int, idx: np.ndarray, grid: tuple, tiles: int, layers: int,
                  progress: Progress, pool, raht_classes: int) -> Layer:
    """One part (layer ``li`` of tile ``t``) in this process: its GEOM (on the thread ``pool``
    when given, while the transform runs here), the Euler angles and the RAHT of its attributes
    over its own tree."""
    job = _part_job(vox, idx, grid, raht_weights(vox.importance[idx], raht_classes))
    tag = _part_tag(li, t, len(idx), tiles, layers)

    def code_geometry():
        with progress.stage("geometry", tag):
            return write_geometry(job.ijk, *job.grid)
    geom = pool.submit(code_geometry) if pool is not None else code_geometry()
    with progress.stage("transform", ("Euler + RAHT, " + tag) if tag else "Euler + RAHT"):
        codes, dc, ac = _transform(job.ijk, grid[2], job.rotations, job.opacities, job.sh_dc, job.weights)
    return Layer(index=idx, geometry_job=geom, raht_dc=dc, raht_ac=ac,
                 scales=_stored_scales(vox, idx, job.weights), codes=codes,
                 layer=li, tile=t, grid=grid, raht_weights=job.weights)


def _stored_scales(vox, idx: np.ndarray, weights) -> np.ndarray:
    """float32 [3, M_l] the part's log-scales in the order its direct set stores them."""
    sel = idx if weights is None else idx[weights.order]
    return np.ascontiguousarray(vox.cloud.scales[sel].T, dtype=np.float32)


def _prepare_parts(vox, part_of: list, grids: list, layers: int, progress: Progress, pool, executor,
                   raht_classes: int) -> list:
    """Every part's Layer; a tiled stage's parts run on ``executor`` (when given)."""
    tiles = len(grids)
    if executor is None or tiles == 1:
        return [_prepare_part(vox, li, t, idx, grids[t], tiles, layers, progress, pool, raht_classes)
                for li, t, idx in part_of]
    with progress.stage("tiles", f"geometry + transform of {len(part_of)} parts ({tiles} tiles) on "
                                 f"{executor.name} ({executor.workers} workers)"):
        # coded here, each part's job is made in its turn (all at once: 56 bytes a voxel)
        weights = [raht_weights(vox.importance[idx], raht_classes) for _, _, idx in part_of]
        done = in_order(executor, code_part, (_part_job(vox, idx, grids[t], w)
                                              for (_, t, idx), w in zip(part_of, weights)),
                        gaussians=len(vox.ijk))
        return [Layer(index=idx, geometry_job=geom, raht_dc=dc, raht_ac=ac,
                      scales=_stored_scales(vox, idx, w), codes=codes,
                      layer=li, tile=t, grid=grids[t], raht_weights=w)
                for (li, t, idx), w, (geom, codes, dc, ac) in zip(part_of, weights, done)]


@dataclass
class AttributeJob:
    """One part's coefficients and bit-widths: what coding its ATTR chunk needs (a worker's job)."""
    raht_dc: np.ndarray
    raht_ac: np.ndarray
    scales: np.ndarray
    codes: np.ndarray
    depth: int
    raht_bits: object
    scale_bits: object
    blocks: int
    leaf_weights: object = None
    scale_order: object = None
    decode: bool = True


def code_attributes(job: AttributeJob):
    """:func:`attribute_chunk` of a job (the executor's unit of work)."""
    return attribute_chunk(job, job.raht_bits, job.scale_bits, job.blocks, job.decode)


def attribute_chunk(layer: Layer, raht_bits, scale_bits, blocks: int, decode: bool = True):
    """One layer's ATTR chunk payload for the given bit-widths (int, or [7, B] / [3, B] arrays),
    the attributes the decoder will reconstruct (None unless ``decode``), and per-part byte
    counts."""
    w = Writer()
    w.u8(ROTATION_EULER_ZYX).u8(len(RAHT_CHANNELS)).array(layer.raht_dc, np.float64)
    # the two channel sets are independent: coded side by side where there are cores
    (ac_bytes, ac_rec), (sc_bytes, sc_rec) = thread_map(
        lambda i: (write_channel_set(layer.raht_ac, raht_bits, blocks) if i == 0
                   else write_channel_set(layer.scales, scale_bits, blocks)), 2)
    w.bytes(ac_bytes).bytes(sc_bytes)
    decoded = layer_attributes(layer, layer.raht_dc, ac_rec, sc_rec) if decode else None
    return w.getvalue(), decoded, {"raht_bytes": len(ac_bytes), "scale_bytes": len(sc_bytes)}


def layer_attributes(layer, dc: np.ndarray, ac: np.ndarray, direct: np.ndarray, dest: OutputRows = FRESH):
    """The Attributes a decoder makes of a part's reconstructed coefficients: RAHT DC [7], AC
    [7, M_l - 1] and the direct set [3, M_l] in the order the part stores it; the fields go to
    ``dest``."""
    from ..decoder.attributes import attributes_from_coefficients

    if layer.scale_order is not None:          # stored in class order: back to point order
        rec = np.empty_like(direct)
        rec[:, layer.scale_order] = direct
        direct = rec
    # the decoder's own inverse (its C path where built): the encoder's picture of a file is
    # the decoder's
    return attributes_from_coefficients(dc, ac, direct, layer.codes, layer.depth,
                                        leaf_weights=layer.leaf_weights, dest=dest)


def _gathered(stage: Stage, parts) -> "Attributes":
    """The stage's Attributes in output order from each part's, in turn (an iterable): filled
    part by part, no list of parts beside their concatenation."""
    from ..decoder.attributes import Attributes

    fields_, out, end = ("opacities", "rotations", "sh_dc", "scales"), None, 0
    for dec in parts:
        if out is None:
            out = {f: np.empty((stage.num_points,) + getattr(dec, f).shape[1:], getattr(dec, f).dtype)
                   for f in fields_}
        n = len(dec.opacities)
        for f in fields_:
            out[f][end:end + n] = getattr(dec, f)
        end += n
    return Attributes(**out)


def payload_attributes(stage: Stage, payloads: list) -> "Attributes":
    """The Attributes, in output order, that a decoder reconstructs from the stage's ATTR
    payloads (one per part): the decoder's own parse, so a search round need not hold its
    decoded attributes until it is rendered.  Parts run side by side, each into its rows."""
    from ..decoder.attributes import Attributes, parse_attributes

    n = stage.num_points
    arrays = dict(opacities=np.empty(n, np.float32), rotations=np.empty((n, 4), np.float32),
                  sh_dc=np.empty((n, 3), np.float32), scales=np.empty((n, 3), np.float32))
    starts = np.cumsum([0] + [len(l.codes) for l in stage.layers])

    def part(li: int) -> None:
        layer, dest = stage.layers[li], OutputRows(arrays, int(starts[li]), int(starts[li + 1]))
        dc, ac, direct = parse_attributes(payloads[li], len(layer.codes))
        dec = layer_attributes(layer, dc, ac, direct, dest)
        for f, a in arrays.items():
            got = getattr(dec, f)
            if not dest.holds(f, got):
                a[dest.start:dest.stop] = got.reshape(a[dest.start:dest.stop].shape)
    thread_map(part, len(stage.layers))
    return Attributes(**arrays)


def attribute_chunks(stage: Stage, bits, blocks: int, decode: bool = True):
    """Every layer's ATTR payload.  ``bits``: an int (uniform) or, per layer, a pair
    (raht_bits [7, B_l], scale_bits [3, B_l]).  Returns ([payload per layer], decoded
    Attributes in output order -- None unless ``decode`` (:func:`payload_attributes` makes
    them later) --, summed byte counts)."""
    payloads, stats = [], {"raht_bytes": 0, "scale_bytes": 0}
    jobs = (AttributeJob(layer.raht_dc, layer.raht_ac, layer.scales, layer.codes, layer.depth,
                         *((bits, bits) if np.isscalar(bits) else bits[li]), b, layer.leaf_weights,
                         layer.scale_order, decode)
            for li, (layer, b) in enumerate(zip(stage.layers, stage.layer_blocks(blocks))))
    ex = stage.executor if stage.num_tiles > 1 else None

    def parts():
        for data, dec, st in in_order(ex, code_attributes, jobs, gaussians=stage.num_points):
            payloads.append(data)
            for k in stats:
                stats[k] += st[k]
            yield dec
    if decode:
        return payloads, _gathered(stage, parts()), stats
    for _ in parts():
        pass
    return payloads, None, stats


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


def sh_set_blocks(entries: int, blocks: int) -> int:
    """Blocks per component of an SH vector set -- the codebook, or one layer's kept exact
    vectors: one per 128 vectors (at most ``blocks``).  The vectors' components span similar
    ranges whatever their order, while every block costs 9 bytes of metadata per component
    (45 x 80 x 9 = 32 kB for a degree-3 set at 80 blocks; tiny_graphdeco's 71 kept vectors in
    71 one-vector blocks cost 28.9 kB, 72 bits per coefficient, at 12 bits)."""
    return max(1, min(int(blocks), int(entries) // 128))


def tile_assignment(stage: Stage, codebook: np.ndarray, near: np.ndarray, assign) -> np.ndarray:
    """The codeword of every voxel [M] in a tiled stage: ``near`` (nearest of all K) with each
    tile limited to its share of the codebook (:func:`tile_codewords`); ``near`` itself for
    one tile.  Idempotent, and independent of which vectors are later kept exact."""
    if stage.num_tiles == 1:
        return near
    out = np.asarray(near, np.int64).copy()
    m = out.shape[0]
    for t in range(stage.num_tiles):
        members = np.concatenate([l.index for l in stage.layers if l.tile == t])
        out[members] = tile_codewords(stage.sh[members], out[members], codebook, len(members) / m, assign)
    return out


def tile_codewords(vectors: np.ndarray, near: np.ndarray, codebook: np.ndarray, share: float,
                   assign) -> np.ndarray:
    """Codeword of each of a tile's ``vectors`` when the tile may carry only its ``share`` of
    the codebook's K words (so T tiles carry about one codebook in all, not T): the tile keeps
    its most used words (ties: lower index) and the vectors of the others move to their
    nearest kept word."""
    k = codebook.shape[0]
    cap = max(16, int(round(k * share)))
    counts = np.bincount(near, minlength=k)
    if np.count_nonzero(counts) <= cap:
        return near
    keep = np.sort(np.lexsort((np.arange(k), -counts))[:cap])
    allowed = np.zeros(k, bool)
    allowed[keep] = True
    out = near.copy()
    move = ~allowed[near]
    out[move] = keep[assign(vectors[move], codebook[keep])]
    return out


def sh_chunk(stage: Stage, codebook: np.ndarray, keep: int, sh_bits: int, blocks: int,
             cb_blocks: int | None = None, index: np.ndarray | None = None):
    """SHVQ payloads (one per layer), the SH the decoder will reconstruct ([M, K, 3] float32,
    output order), and stats: ``ShPayloads(...).payloads()`` (see there) with every kept vector
    at ``sh_bits`` like the codebook."""
    return ShPayloads(stage, codebook, keep, sh_bits, blocks, cb_blocks, index).payloads()


#: rows per step where a pass over every voxel's SH vector would otherwise gather [M, D] copies
ROW_CHUNK = 65536


def gather_columns(sh, rows: np.ndarray, minus=None) -> np.ndarray:
    """float32 [D, n]: SH rows ``rows`` of ``sh`` ([M, D] rows, an array or SourcedRows) as
    columns, ``minus(s, e)`` (float32 [e - s, D]) subtracted from rows s..e first when given.
    ROW_CHUNK rows at a time on every core, each its own columns: a whole [n, D] gather beside
    its transposed copy was 180 MB more for 2^20 vectors (~700 MB for a 6 M stage's top third)."""
    out = np.empty((sh.shape[1], rows.size), np.float32)

    def gather(s: int, e: int) -> None:
        r = np.asarray(sh[rows[s:e]], np.float32)
        if minus is not None:
            r = r - minus(s, e)
        out[:, s:e] = r.T
    for_ranges(rows.size, ROW_CHUNK, gather)
    return out


class ShPayloads:
    """The SHVQ payloads of one (stage, codebook, keep-count), with the kept vectors' group
    bit-widths still open: the codebook, the codeword indices and the kept flags are coded
    once here, each :meth:`payloads` call codes only the kept vectors' channel sets (the size
    search allocates their bit-widths together with the attributes').

    ``cb_blocks``: blocks of the codebook ChannelSet (default :func:`sh_set_blocks`); the kept
    vectors of each layer get :func:`sh_set_blocks` of their count.
    ``index``: [M] nearest codeword of every voxel's vector when the caller has it (the size
    search assigns once per stage and codebook), else computed here.
    The ``keep`` most important Gaussians keep their exact vectors (quantised group-wise,
    ``sh_bits`` by default); every other Gaussian takes its nearest codeword (codebook at
    ``cb_bits``, default ``sh_bits``).  Each tile's codebook (compacted to the codewords its
    layers use) goes with its first layer that has codeword indices (layer 0 when none has), so
    a layer whose Gaussians all keep their exact vectors does not wait for it; the tile's other
    layers refer to it.

    ``refine``: the kept vectors are coded as residuals of their nearest codeword (an SHRF chunk
    per part with kept vectors, GSZ.md §8.3): every voxel takes a codeword, the kept ones a
    quantised correction on top (docs/design/sh-refine.md)."""

    def __init__(self, stage: Stage, codebook: np.ndarray, keep: int, sh_bits: int, blocks: int,
                 cb_blocks: int | None = None, index: np.ndarray | None = None, classes: int = 1,
                 cb_bits: int | None = None, refine: bool = False):
        from .rans import encode_stream
        from .vq import assign, compact

        m, d = stage.sh.shape
        self.stage, self.sh_bits, self.m, self.d = stage, int(sh_bits), m, d
        self.keep = keep = min(int(keep), m)
        self.refine = bool(refine) and keep > 0
        kept = top_k_mask(stage.importance, keep)
        rest = ~kept
        coded = np.ones(m, bool) if self.refine else rest      # voxels that take a codeword
        near = None
        if stage.num_tiles > 1:
            near = tile_assignment(stage, codebook, assign(stage.sh, codebook) if index is None
                                   else np.asarray(index, np.int64), assign)
        elif coded.any():
            near = np.zeros(m, np.int64)
            near[coded] = (assign(stage.sh, codebook, rows=np.flatnonzero(coded)) if index is None
                           else np.asarray(index)[coded])
        cb_bits = self.sh_bits if cb_bits is None else int(cb_bits)
        self.stats = {"kept": keep, "codebook_size": 0, "codebook_bytes": 0, "kept_bytes": 0, "index_bytes": 0,
                      "codebook_bits": cb_bits}
        #: per part: (kept voxel indices in coding order, blocks of their channel set)
        self.kept_sets = [None] * len(stage.layers)
        self._heads, self._tails = [None] * len(stage.layers), [None] * len(stage.layers)
        #: per part: SHCL payload (None: kept vectors in Morton order) and, with classes, the
        #: importance weight of each block (= class) of the kept set, mean 1 over the stage
        self.class_chunks = [None] * len(stage.layers)
        #: per part: SHRF payload (None: the part's kept vectors are not residuals)
        self.refine_chunks = [None] * len(stage.layers)
        self.block_weights = [None] * len(stage.layers)
        self.classes = int(classes)
        self._weight = None
        #: every voxel's row in the tiles' reconstructed codebooks stacked (float32 [sum K_t, D]),
        #: -1 where it takes none: an [M, D] array per plan would be 216 MB at 1.2 M
        self._cw_row = np.full(m, -1, np.int32)
        self._books = []
        book_rows = 0
        for t in range(stage.num_tiles):
            # every tile carries the codewords its Gaussians use (a tile decodes on its own)
            parts = [(pi, l) for pi, l in enumerate(stage.layers) if l.tile == t]
            members = np.concatenate([l.index for _, l in parts])
            r = members[coded[members]]
            idx_all = np.zeros(m, np.int64)
            if r.size:
                cb, idx = compact(codebook, near[r])
                idx_all[r] = idx
            else:
                cb = np.zeros((1, d), np.float32)
            cb_bytes, cb_rec = write_channel_set(
                cb.T, cb_bits, sh_set_blocks(cb.shape[0], blocks) if cb_blocks is None else cb_blocks)
            rec32 = np.ascontiguousarray(cb_rec.T, np.float32)
            self._cw_row[r] = idx_all[r] + book_rows
            self._books.append(rec32)
            book_rows += rec32.shape[0]
            self.stats["codebook_size"] += int(cb.shape[0])
            self.stats["codebook_bytes"] += len(cb_bytes)
            kept_counts = [int(kept[l.index].sum()) for _, l in parts]
            # the codebook goes with the tile's first part whose Gaussians use a codeword
            cb_part = next((pi for (pi, l), p in zip(parts, kept_counts)
                            if p < l.num_points or (self.refine and p)), parts[0][0])
            for (pi, layer), p in zip(parts, kept_counts):
                self._code_part(pi, layer, kept, p, idx_all, cb_bytes if pi == cb_part else None,
                                int(cb.shape[0]), blocks, encode_stream)
        self._books = (np.concatenate(self._books) if self._books
                       else np.zeros((0, d), np.float32))

    def _code_part(self, pi, layer, kept, p, idx_all, cb_bytes, cb_size, blocks, encode_stream):
        """Head (codebook when ``cb_bytes``) and tail (kept flags, codeword indices) of part pi."""
        d = self.d
        k_l = kept[layer.index]
        sel = layer.index[k_l]
        q = self.classes if p >= SH_CLASS_MIN_SIZE * self.classes else 1
        if q > 1:
            cls = importance_classes(self.stage.importance[sel], q)
            sel = sel[class_order(cls)]
            rw = layer.raht_weights
            if rw is not None and rw.weights.shape[0] == q and np.array_equal(rw.classes[k_l], cls):
                # the kept points' RWGT classes: the part's RWGT chunk carries them already
                self.class_chunks[pi] = Writer().u8(SH_CLASSES_FROM_RWGT).getvalue()
            else:
                self.class_chunks[pi] = (Writer().u8(q).blob(encode_stream(cls, np.zeros(p, np.int64), 1))
                                         .getvalue())
            w = self._class_weight()
            self.block_weights[pi] = np.array([w[sel[s:e]].mean() for s, e in _block_bounds(p, q)])
        self.kept_sets[pi] = (sel, q if q > 1 else sh_set_blocks(p, blocks))
        if self.refine and p:
            # each kept vector's codeword, in the order its channel set stores it
            ref = encode_stream(idx_all[sel], np.zeros(p, np.int64), 1)
            self.refine_chunks[pi] = Writer().blob(ref).getvalue()
            self.stats["index_bytes"] += len(ref) + 8
        w = Writer()
        w.u32(cb_size if cb_bytes is not None else 0).u32(p).u16(d)
        if cb_bytes is not None:
            w.bytes(cb_bytes)
        self._heads[pi] = w.getvalue()
        w = Writer()
        if p:
            flags = encode_stream(k_l.astype(np.int64), np.zeros(layer.num_points, np.int64), 1)
            w.blob(flags)
            self.stats["kept_bytes"] += len(flags) + 8
        li_idx = idx_all[layer.index[~k_l]]
        idx_blob = encode_stream(li_idx, np.zeros(li_idx.size, np.int64), 1)
        w.blob(idx_blob)
        self.stats["index_bytes"] += len(idx_blob) + 8
        self._tails[pi] = w.getvalue()

    def _class_weight(self) -> np.ndarray:
        """[M] each voxel's importance^SH_CLASS_WEIGHT_EXP over the stage's mean (once per stage)."""
        if self._weight is None:
            w = self.stage.importance ** SH_CLASS_WEIGHT_EXP
            self._weight = w / (float(w.mean()) or 1.0)
        return self._weight

    @property
    def fixed_bytes(self) -> int:
        """Bytes of the payloads apart from the kept vectors' channel sets (SHCL and SHRF chunks
        and their table entries included)."""
        cls = [c for c in self.class_chunks + self.refine_chunks if c is not None]
        return (sum(map(len, self._heads)) + sum(map(len, self._tails))
                + sum(map(len, cls)) + CHUNK_ENTRY_SIZE * len(cls))

    def kept_vectors(self, layer: int) -> np.ndarray:
        """float32 [D, P_l]: the kept vectors of a layer as their channel set codes them (with
        ``refine``, minus their codewords)."""
        sel = self.kept_sets[layer][0]
        return gather_columns(self.stage.sh, sel,
                              (lambda s, e: self.codewords_of(sel[s:e])) if self.refine else None)

    def codewords_of(self, voxels: np.ndarray) -> np.ndarray:
        """float32 [n, D]: the reconstructed codeword of each of ``voxels`` (each takes one)."""
        return self._books[self._cw_row[voxels]]

    def payloads(self, kept_bits=None, decoded: bool = True):
        """(payloads per layer, SH as decoded [M, K, 3] output order, stats).  ``kept_bits``:
        per layer an int or int array [D, B_l] (B_l = blocks_for(P_l, its kept_sets blocks));
        default every group at ``sh_bits``.  ``decoded`` False: None instead of the SH (the
        same payloads; the size search codes them again for the one file it renders)."""
        out = None
        if decoded:
            order = self.stage.order
            pos = np.empty(self.m, np.int64)       # voxel -> its row in the output
            pos[order] = np.arange(self.m)
            out = np.empty((self.m, self.d), np.float32)
            coded = np.flatnonzero(self._cw_row >= 0)

            def put(s: int, e: int) -> None:    # a range at a time: the whole gather is 1 GB at 6 M
                out[pos[coded[s:e]]] = self.codewords_of(coded[s:e])
            for_ranges(coded.size, ROW_CHUNK, put)
        stats = dict(self.stats)
        # without ``decoded`` the reconstruction is not made (180 MB a part of 2^20 kept vectors)
        jobs = ((self.kept_vectors(li), self.sh_bits if kept_bits is None else kept_bits[li], kb,
                 np.float32 if decoded else None)
                for li, (sel, kb) in enumerate(self.kept_sets) if sel.size)
        ex = self.stage.executor if self.stage.num_tiles > 1 else None
        coded = in_order(ex, _code_channel_set, jobs, gaussians=self.m)
        payloads = []
        for li, (sel, kb) in enumerate(self.kept_sets):
            body = b""
            if sel.size:
                body, rec = next(coded)
                if out is not None:
                    # the decoder's float32 sum of the residual and its codeword (GSZ.md §8.3)
                    out[pos[sel]] = rec.T + self.codewords_of(sel) if self.refine else rec.T
                stats["kept_bytes"] += len(body)
            payloads.append(self._heads[li] + body + self._tails[li])
        k = self.m and self.d // 3
        return payloads, None if out is None else out.reshape(self.m, k, 3), stats

    def decoded_rows(self, kept_bits=None) -> MadeRows:
        """The SH ``payloads(kept_bits)`` decodes to ([M, K, 3] float32, output order), bit for
        bit, as :class:`MadeRows` made 64 k rows at a time (for a render): from each tile's
        codebook, and for a kept vector from its own values quantised again with its group's
        parameters (those its channel set codes, found once here without entropy coding: the
        normative quantiser and dequantiser, kernels.quantize, are elementwise).  It holds the
        groups' parameters and 12 bytes of row indices a voxel, neither the [M, K, 3] float32
        array (1 GB at 6 M voxels) nor the kept vectors' symbols (270 MB on the scalar path)."""
        from ..decoder.groups import blocks_for
        from ..decoder.quant import split_lengths, step_sizes
        from .groups import quantize_channel_set
        m, d = self.m, self.d
        order = self.stage.order                 # output row -> its voxel
        pos = np.empty(m, np.int64)              # voxel -> its row in the output
        pos[order] = np.arange(m)
        cw_row = np.empty(m, np.int32)           # output row -> its row in the stacked codebooks
        cw_row[pos] = self._cw_row
        books = self._books
        group = np.full(m, -1, np.int32)         # output row -> its kept group's row (-1: a codeword)
        lo, step, top = [np.zeros((0, d))], [np.zeros((0, d))], [np.zeros((0, d))]
        g = 0
        for li, (sel, kb) in enumerate(self.kept_sets):
            if not sel.size:
                continue
            bits = np.broadcast_to(np.asarray(self.sh_bits if kept_bits is None else kept_bits[li]),
                                   (d, blocks_for(sel.size, kb)))
            x = self.kept_vectors(li)
            mins, maxs, qbits = [], [], []
            # QUANT_CHANNELS channels at a time (groups are per channel: the same parameters),
            # so that no [D, P] int32 symbols exist (360 MB with a part of 2^20)
            for c in range(0, d, QUANT_CHANNELS):
                _, mn, mx, qb = quantize_channel_set(x[c:c + QUANT_CHANNELS], bits[c:c + QUANT_CHANNELS], kb)
                mins.append(mn), maxs.append(mx), qbits.append(qb)
            del x
            mins, maxs, qbits = np.concatenate(mins), np.concatenate(maxs), np.concatenate(qbits)
            group[pos[sel]] = g + np.repeat(np.arange(qbits.shape[1], dtype=np.int32),
                                            split_lengths(sel.size, qbits.shape[1]))
            # the quantiser's parameters: float32 minimum widened, normative float64 step, top
            # symbol 2^q - 1 (0 for a width-0 group: constant_groups gives it symbols 0)
            lo.append(mins.astype(np.float64).T)
            step.append(step_sizes(mins, maxs, qbits).T)
            top.append(np.where(bits == 0, 0.0, np.ldexp(1.0, qbits) - 1.0).T)
            g += qbits.shape[1]
        lo, step, top = np.concatenate(lo), np.concatenate(step), np.concatenate(top)
        del pos
        sh = self.stage.sh
        from ..decoder import native
        # one C pass per row where the accelerator is built, the same operations (the NumPy
        # below is the reference)
        in_c = native.enabled() and d > 0 and sh.dtype == np.float32
        books = np.ascontiguousarray(books, np.float32)

        def rows(a: int, b: int) -> np.ndarray:
            out = np.empty((b - a, d), np.float32)
            gr = group[a:b]
            kept = gr >= 0
            # the kept rows gathered a range at a time (the stage's SH rows are references to
            # the input's: whole, 1 GB at 6 M voxels)
            src = sh[order[a:b][kept]]
            ref = None
            if self.refine:         # residuals requantised, their codewords added back
                ref = books[cw_row[a:b][kept]]
                src = np.asarray(src, np.float32) - ref
            if in_c:
                src = np.ascontiguousarray(src, np.float32).reshape(-1, d)
                at = np.cumsum(kept, dtype=np.int64) - 1          # a kept row's row of src
                native.module().sh_requant_rows(src, at, gr, cw_row[a:b], books, lo, step, top, out)
                if ref is not None:
                    out[kept] += ref
                return out.reshape(b - a, -1, 3)
            if kept.any():
                gr = gr[kept]
                # quantize_cpu.quantize's k = min(max(rint((x - m) / s), 0), 2^q - 1), then
                # dequantize_groups' s * k + m, both in float64
                v = src.astype(np.float64)
                m_g, s_g = lo[gr], step[gr]
                v -= m_g
                v /= s_g
                np.rint(v, out=v)
                np.maximum(v, 0.0, out=v)
                np.minimum(v, top[gr], out=v)
                v *= s_g
                v += m_g
                out[kept] = v
                if ref is not None:
                    out[kept] += ref
            if not kept.all():
                out[~kept] = books[cw_row[a:b][~kept]]
            return out.reshape(b - a, -1, 3)
        return MadeRows((m, m and d // 3, 3), rows)


#: importance classes of the kept SH vectors wherever the size search allocates their widths
#: (the scalar path, the classes candidate; docs/design/sh-classes.md); a part with fewer than
#: SH_CLASS_MIN_SIZE kept vectors per class keeps them in Morton order; the class weight is
#: importance^SH_CLASS_WEIGHT_EXP (1 measured best of 0.5, 1, 1.5)
SH_CLASSES = 8
SH_CLASS_MIN_SIZE = 256
SH_CLASS_WEIGHT_EXP = 1.0


def importance_classes(importance: np.ndarray, q: int) -> np.ndarray:
    """Class [P] of each kept vector (Morton order): class c holds the c-th of ``q`` equal
    runs by descending importance (ties: Morton order), sized like the kept ChannelSet's
    ``q`` blocks, so that each block of the class-ordered set is one class."""
    from ..decoder.quant import split_lengths
    rank = np.lexsort((np.arange(importance.shape[0]), -importance))
    out = np.empty(importance.shape[0], np.int64)
    out[rank] = np.repeat(np.arange(q), split_lengths(importance.shape[0], q))
    return out


def _block_bounds(length: int, blocks: int):
    """(start, end) of each block of a channel of ``length`` cut into ``blocks``."""
    from ..decoder.quant import split_lengths
    lens = split_lengths(length, blocks)
    ends = np.cumsum(lens)
    return zip(ends - lens, ends)


def _code_channel_set(job):
    """write_channel_set(values, bits, blocks, recon_dtype) of one job (an executor's unit of
    work): its reconstruction float32 (the SH output's type), or None."""
    return write_channel_set(*job[:3], recon_dtype=job[3])


def assemble(stage: Stage, attr: list, decoded, sh: list | None, sh_rest, meta: dict,
             sh_classes: list | None = None, sh_refine: list | None = None):
    """The .gsz bytes and the cloud the decoder will reconstruct (:func:`write_file`; decoded,
    sh_rest in output order)."""
    positions = stage.positions()
    data, meta_len = write_file(stage, positions, attr, sh, meta, sh_classes, sh_refine)
    if sh is not None:
        sh_rest = decoded_sh_rest(sh_rest, stage.sh_colour)     # what the decoder turns them into
    if stage.sh_colour & SH_COLOUR_DC:
        decoded = dataclasses.replace(decoded, sh_dc=luma_chroma_to_rgb(decoded.sh_dc))
    return data, decoded_cloud(stage, positions, decoded, sh_rest if sh is not None else None), meta_len


def decoded_cloud(stage: Stage, positions: np.ndarray, decoded, sh_rest) -> GaussianCloud:
    """The cloud a decoder reconstructs from a file of ``stage``: its ``positions`` (output
    order), ``decoded`` Attributes and ``sh_rest`` [M, K, 3] (None: the file has no SH rest)."""
    return GaussianCloud(
        positions=positions, scales=decoded.scales, rotations=decoded.rotations,
        opacities=decoded.opacities, sh_dc=decoded.sh_dc,
        sh_rest=np.zeros((stage.num_points, 0, 3), np.float32) if sh_rest is None else sh_rest,
        sh_degree=stage.sh_degree)


def sh_colour_chunk(transform: int, with_matrix: bool = True) -> bytes:
    """An SHXF chunk's payload (GSZ.md §8.2): the transform bits; with the KLT bit, the matrix
    (``transform.klt``) where ``with_matrix`` (a tile's first layer), else D = 0 (the tile's)."""
    if not transform & SH_COLOUR_KLT:
        return bytes([int(transform)])
    klt = transform.klt if with_matrix else np.zeros((0, 0), np.int16)
    return bytes([int(transform), klt.shape[0]]) + np.ascontiguousarray(klt, "<i2").tobytes()


def sh_colour_payload_bytes(stage: Stage) -> int:
    """Bytes of the stage's SHXF chunk payloads (:func:`sh_colour_chunk`: one per part, the KLT
    matrix in each tile's first)."""
    if not stage.sh_colour:
        return 0
    per_part = len(sh_colour_chunk(stage.sh_colour, False))
    tiles = len({part.tile for part in stage.layers})
    return per_part * len(stage.layers) + tiles * (len(sh_colour_chunk(stage.sh_colour)) - per_part)


def write_file(stage: Stage, positions: np.ndarray, attr: list, sh: list | None, meta: dict,
               sh_classes: list | None = None, sh_refine: list | None = None) -> tuple[bytes, int]:
    """(the .gsz bytes, META chunk bytes) of ``stage`` with its decoded ``positions`` (output
    order, :meth:`Stage.positions`).

    attr / sh   per-part ATTR / SHVQ payloads.  A stage of several tiles gets a TILE chunk first
                and format version 1.2.
    sh_classes  per part the SHCL payload or None; any SHCL makes the file version 1.3, any
                direct-coded geometry (OCTREE.md scheme 1) 1.4.  A stage coded in a colour
                transform (``stage.sh_colour``) gets an SHXF chunk per part and version 1.6,
                1.7 when it turns the DC colour, 1.8 with the SH KLT (its matrix in each
                tile's first layer).
    sh_refine   per part the SHRF payload or None; any SHRF makes the file version 1.9."""
    import zstandard
    from ..decoder.container import (MINOR_DIRECT, MINOR_LAYERS, MINOR_RAHT_WEIGHTS, MINOR_SH_CLASSES,
                                     MINOR_DC_COLOUR, MINOR_SH_COLOUR, MINOR_SH_KLT, MINOR_SH_REFINE,
                                     MINOR_TILES, TILE_SHIFT, VERSION_MAJOR)
    from ..decoder.geometry import octree_scheme
    from ..decoder.octree import SCHEME_DIRECT
    from ..decoder.layout import CHUNK_TILE
    from ..decoder.tiles import TileInfo, pack_tile_table

    m = stage.num_points
    chunks = []
    tiles = stage.num_tiles
    if tiles > 1:
        ends = np.cumsum([l.num_points for l in stage.layers])
        rows = []
        for t in range(tiles):
            sel = np.concatenate([np.arange(e - l.num_points, e) for l, e in zip(stage.layers, ends)
                                  if l.tile == t])
            p = positions[sel]
            rows.append(TileInfo(tuple(p.min(0)), tuple(p.max(0)), len(sel)))
        chunks.append(Chunk(CHUNK_TILE, pack_tile_table(rows), CHUNK_REQUIRED))
    matrix_tiles = set()
    for pi, part in enumerate(stage.layers):
        flags = CHUNK_REQUIRED | (part.layer << LAYER_SHIFT) | (part.tile << TILE_SHIFT)
        chunks.append(Chunk(CHUNK_GEOM, part.geometry, flags))
        if part.raht_weights is not None:
            chunks.append(Chunk(CHUNK_RWGT, part.weights_chunk, flags))
        chunks.append(Chunk(CHUNK_ATTR, attr[pi], flags))
        if stage.sh_colour:
            # parts go layer by layer: a tile's first is its layer 0, which carries the matrix
            payload = sh_colour_chunk(stage.sh_colour, with_matrix=part.tile not in matrix_tiles)
            chunks.append(Chunk(CHUNK_SHXF, payload, flags))
            matrix_tiles.add(part.tile)
        if sh is not None:
            if sh_classes is not None and sh_classes[pi] is not None:
                chunks.append(Chunk(CHUNK_SHCL, sh_classes[pi], flags))
            if sh_refine is not None and sh_refine[pi] is not None:
                chunks.append(Chunk(CHUNK_SHRF, sh_refine[pi], flags))
            chunks.append(Chunk(CHUNK_SHVQ, sh[pi], flags))
    meta_bytes = zstandard.ZstdCompressor(level=19).compress(
        json.dumps(meta, sort_keys=True, separators=(",", ":"), default=float).encode())
    chunks.append(Chunk(CHUNK_META, meta_bytes, 0))
    header = FileHeader(num_gaussians=m, sh_degree=stage.sh_degree, frame=FRAME_RDF,
                        bbox_min=tuple(positions.min(0)),
                        bbox_max=tuple(positions.max(0)),
                        version=(VERSION_MAJOR,
                                 MINOR_SH_REFINE if any(c.type == CHUNK_SHRF for c in chunks)
                                 else MINOR_SH_KLT if stage.sh_colour & SH_COLOUR_KLT
                                 else MINOR_DC_COLOUR if stage.sh_colour & SH_COLOUR_DC
                                 else MINOR_SH_COLOUR if any(c.type == CHUNK_SHXF for c in chunks)
                                 else MINOR_RAHT_WEIGHTS if any(c.type == CHUNK_RWGT for c in chunks)
                                 else MINOR_DIRECT if any(c.type == CHUNK_GEOM and octree_scheme(c.data) == SCHEME_DIRECT
                                                     for c in chunks)
                                 else MINOR_SH_CLASSES if any(c.type == CHUNK_SHCL for c in chunks)
                                 else MINOR_TILES if tiles > 1 else MINOR_LAYERS))
    return write_container(header, chunks), len(meta_bytes)


def compute_train_importance(cloud: GaussianCloud, opts: SceneOptions, *, cameras=None,
                             progress: Progress | None = None) -> np.ndarray:
    """Importance I = I_d * (V/V_ref)^beta over the train views (default camera set if None)."""
    from ..evaluation.cameras import load_cameras
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
           importance: np.ndarray | None = None, progress: Progress | None = None,
           source: str | None = None, reuse_input: bool = False) -> EncodeResult:
    """Compress ``cloud`` with ``options``; ``cameras`` are the train views for importance
    (default: the deterministic default camera set).  ``importance`` [N] skips the importance
    pass when the caller already has it (e.g. several encodes of one scene).  Absurd values are
    bounded and far-away Gaussians dropped first (:mod:`gsz.encoder.sanitize`: one
    GszInputWarning per fix, naming ``source``).  Returns the .gsz bytes, the cloud the decoder
    will reconstruct, and a report (sizes per component, seconds per stage, input fixes).
    ``reuse_input``: the caller is done with ``cloud``; its arrays may be overwritten instead
    of copied (the colour transform of the SH rest and DC)."""
    from .sanitize import fixes_report, sanitize_cloud
    opts = (options or EncodeOptions()).validate()
    progress = progress or Progress(quiet=True)
    cloud.validate()
    n_in = len(cloud)
    t_start, c_start = time.perf_counter(), time.process_time()
    if importance is not None:
        importance = np.asarray(importance, np.float64)
        if importance.shape != (n_in,) or not np.all(np.isfinite(importance)):
            raise EncodeOptionsError(f"importance must be {n_in} finite values")
    cloud, fixes, kept = sanitize_cloud(cloud, source)
    if importance is None:
        importance = compute_train_importance(cloud, opts, cameras=cameras, progress=progress)
    elif kept is not None:
        importance = importance[kept]
    with progress.stage("sh-colour", "colour space of the SH rest and DC"):
        colour = choose_sh_colour(cloud, opts.sh_colour, tile_gaussians=opts.tile_gaussians)
        cloud = coded_cloud(cloud, colour, in_place=reuse_input)
    from .executor import make_executor
    executor = make_executor(opts.executor, opts.workers)
    try:
        result = _encode_stage(cloud, opts, importance, executor, progress, (t_start, c_start), colour)
    finally:
        executor.close()
    if fixes:                  # only then: the reports of clean scenes stay as they were
        result.report.input_fixes = fixes_report(fixes)
    return result


def _encode_stage(cloud, opts: EncodeOptions, importance, executor, progress, starts,
                  colour: int = 0) -> EncodeResult:
    """The encode after importance; ``starts``: (perf_counter, process_time) at its beginning;
    ``cloud``'s SH rest and DC are in the colour space ``colour`` (SHXF transform bits)."""
    n_in = len(cloud)
    stage = prepare_stage(cloud, importance, opts.reserve, depth=opts.depth,
                          rel_error=opts.rel_error, layers=opts.layers, first_layer=opts.first_layer,
                          progress=progress, tile_gaussians=opts.tile_gaussians, executor=executor,
                          raht_classes=opts.raht_classes, sh_colour=colour)
    m = stage.num_points
    blocks = default_blocks(opts.bits) if opts.blocks is None else int(opts.blocks)
    sh_blocks = default_blocks(opts.sh_bits or opts.bits) if opts.blocks is None else int(opts.blocks)
    with progress.stage("attributes", f"{opts.bits} bits, {blocks} blocks"):
        attr, decoded, attr_stats = attribute_chunks(stage, opts.bits, blocks)
    sh = sh_rest = sh_classes = sh_refine = None
    sh_stats = {}
    if cloud.sh_degree > 0:
        k = default_codebook_size(m, opts.codebook)
        with progress.stage("sh", f"codebook {k}"):
            cb = train_sh_codebook(stage, k, seed=opts.seed, iters=opts.vq_iters, progress=progress)
            keep = int(round(0.01 * m)) if opts.keep is None else int(opts.keep)
            payloads = ShPayloads(stage, cb, keep, int(opts.sh_bits or opts.bits), sh_blocks,
                                  classes=int(opts.sh_classes), refine=bool(opts.sh_refine))
            sh, sh_rest, sh_stats = payloads.payloads()
            sh_classes, sh_refine = payloads.class_chunks, payloads.refine_chunks
    options_json = dict(asdict(opts), depth=stage.depth, blocks=blocks)
    if int(opts.sh_classes) == 1:   # the files of the default stay as they were
        del options_json["sh_classes"]
    if not opts.sh_refine:
        del options_json["sh_refine"]
    if opts.sh_colour == "auto":    # so too here: the file's SHXF chunks say what auto chose
        del options_json["sh_colour"]
    for k in ("executor", "workers"):      # where the work ran does not shape the file
        del options_json[k]
    if stage.num_tiles == 1:       # the option shaped nothing (one-tile files stay 1.1 files)
        del options_json["tile_gaussians"]
    if cloud.sh_degree > 0 and sh_blocks != blocks:
        options_json["sh_blocks"] = sh_blocks
    with progress.stage("container"):
        meta = {"encoder": encoder_name(), "codec": "mesongs++", "options": options_json,
                "input_gaussians": n_in, "voxels": m}
        data, out_cloud, meta_len = assemble(stage, attr, decoded, sh, sh_rest, meta, sh_classes, sh_refine)
    sizes = {"geometry": stage.geometry_bytes, "attributes": sum(map(len, attr)), **attr_stats,
             "metadata": meta_len}
    if sh is not None:
        sizes["sh"] = sum(map(len, sh)) + sum(len(c) for c in sh_classes + sh_refine if c)
        sizes.update({f"sh_{k}": v for k, v in sh_stats.items() if k.endswith("bytes")})
    sizes["container_overhead"] = len(data) - sum(sizes[k] for k in ("geometry", "attributes", "metadata")) \
        - sizes.get("sh", 0)
    report = EncodeReport(
        mode=MODE_FIXED, bytes=len(data), input_gaussians=n_in, voxels=m, bytes_per_gaussian=len(data) / m,
        depth=stage.depth, sh_degree=cloud.sh_degree, reserve=opts.reserve,
        codebook_size=sh_stats.get("codebook_size", 0), sh_keep=sh_stats.get("kept", 0), components=sizes,
        sh_colour=sh_colour_name(stage.sh_colour),
        layers=layer_report(data), seconds=dict(progress.seconds), total_seconds=time.perf_counter() - starts[0],
        memory=progress.memory_report(), cpu_seconds=time.process_time() - starts[1],
        fixed=FixedDetails(kept_after_prune=stage.kept,
                           merged_fraction=stage.merged_fraction, options=options_json))
    return EncodeResult(data=data, cloud=out_cloud, report=report)


def layer_report(data: bytes) -> list[dict]:
    """Per layer of an encoded file: Gaussians and the prefix length that makes it decodable."""
    from ..decoder.container import read_container
    from ..decoder.decode import layer_table
    rows = layer_table(read_container(data))
    for r in rows:
        r["decodable_fraction"] = r["decodable_at"] / len(data)
    return rows
