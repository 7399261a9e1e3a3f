"""Read and write the graphdeco-inria 3DGS PLY layout, and read its common variants.

Layout (one ``vertex`` element, float32 properties)::

    x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3K-1} opacity
    scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3

``f_rest`` is channel-major in the file (all K coefficients of R, then G, then B); in
:class:`GaussianCloud` it is held coefficient-major as ``sh_rest[N, K, 3]``.

Variants read as well, told by their properties: the base colour as ``red green blue`` (uchar,
or float in 0..1) instead of ``f_dc_*`` (nerfstudio's and gsplat's ``rgb`` export mode; SH
degree 0 unless ``f_rest_*`` are there too); 2D Gaussian splatting's surfels (``scale_0
scale_1`` only: the third axis is set to 1/100 of the smaller one, with a warning); any
property order, extra properties (ignored with a warning), other numeric types and either
endianness; and PlayCanvas's compressed PLY (``chunk`` + packed ``vertex`` elements,
:mod:`gsz.decoder.compressed_ply`).
"""
from __future__ import annotations

import os
import warnings

import numpy as np

from .cloud import SH_REST_COUNT, GaussianCloud
from .errors import GszInputWarning, PlyFormatError
from .io_util import atomic_write, check_input_file

_BASE = ["x", "y", "z"]
_DC = ["f_dc_0", "f_dc_1", "f_dc_2"]
_SCALE = ["scale_0", "scale_1", "scale_2"]
_ROT = ["rot_0", "rot_1", "rot_2", "rot_3"]
_NORMALS = ["nx", "ny", "nz"]
_RGB = ["red", "green", "blue"]
#: a 2DGS surfel's missing third log-scale: the smaller in-plane one less ln(100)
SURFEL_THICKNESS_LOG = float(np.log(100.0))
_REST_TO_DEGREE = {3 * k: d for d, k in SH_REST_COUNT.items()}


def read_ply(path, *, check_finite: bool = True) -> GaussianCloud:
    """Read a 3DGS PLY file into a :class:`GaussianCloud` (any SH degree 0..3).

    Properties other than the graphdeco ones are ignored with a warning; a missing property,
    an f_rest count that matches no SH degree, or a non-finite value raises
    :class:`PlyFormatError` naming the file and the property.
    """
    from plyfile import PlyData, PlyParseError

    path = os.fspath(path)
    check_input_file(path, PlyFormatError)     # a regular file of bounded size, before opening
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
            if magic[:3] != b"ply":
                raise PlyFormatError("not a PLY file (missing 'ply' magic line)", path)
            f.seek(0)
            ply = PlyData.read(f)
            _warn_undeclared_data(f, ply, path)
    except PlyFormatError:
        raise
    except (PlyParseError, ValueError, EOFError, OSError, IndexError, KeyError) as e:
        raise PlyFormatError(f"cannot parse PLY: {e}", path) from None
    if "vertex" not in [el.name for el in ply.elements]:
        raise PlyFormatError("has no 'vertex' element", path)
    from .compressed_ply import decode_compressed_ply, is_compressed_ply
    if is_compressed_ply(ply):
        return decode_compressed_ply(ply, path)
    vertex = ply["vertex"]
    data = vertex.data
    names = list(data.dtype.names or ())
    n = len(data)

    rest_names = sorted((p for p in names if p.startswith("f_rest_")),
                        key=lambda s: int(s[7:]) if s[7:].isdigit() else -1)
    for i, p in enumerate(rest_names):
        if p != f"f_rest_{i}":
            raise PlyFormatError(
                f"f_rest properties are not numbered 0..{len(rest_names) - 1} (found '{p}')", path)
    if len(rest_names) not in _REST_TO_DEGREE:
        raise PlyFormatError(
            f"has {len(rest_names)} f_rest properties; expected 0, 9, 24 or 45 (SH degree 0-3)", path)
    degree = _REST_TO_DEGREE[len(rest_names)]
    k = SH_REST_COUNT[degree]

    # nerfstudio/gsplat "rgb" mode: base colour as red/green/blue instead of f_dc
    rgb_colour = not any(p in names for p in _DC) and all(p in names for p in _RGB)
    # 2D Gaussian splatting: flat surfels with two scales
    surfels = "scale_2" not in names and "scale_0" in names and "scale_1" in names
    scale_names = _SCALE[:2] if surfels else _SCALE
    required = _BASE + (_RGB if rgb_colour else _DC) + rest_names + ["opacity"] + scale_names + _ROT
    for p in required:
        if p not in names:
            raise PlyFormatError(f"missing vertex property '{p}'", path)
    known = set(required) | set(_NORMALS)
    extra = [p for p in names if p not in known]
    if extra:
        warnings.warn(f"{path}: ignoring {len(extra)} extra vertex properties: {', '.join(extra[:8])}"
                      + (" ..." if len(extra) > 8 else ""), stacklevel=2)

    # the columns the cloud takes, each field's run contiguous (the rgb colour is read apart)
    needed = _BASE + scale_names + _ROT + ["opacity"] + ([] if rgb_colour else _DC) + rest_names
    at = {p: j for j, p in enumerate(needed)}
    positions, rotations = np.empty((n, 3), np.float32), np.empty((n, 4), np.float32)
    scales, opacities = np.empty((n, 3), np.float32), np.empty(n, np.float32)
    sh_dc = _rgb_dc(data, path) if rgb_colour else np.empty((n, 3), np.float32)
    rest = np.empty((n, k, 3), np.float32)
    # block by block straight into the cloud's arrays ([N, K, 3] SH rest one channel at a time):
    # the file is never held whole beside them
    for lo, hi, block in _row_blocks(data, names, needed, path):
        def cols(ps):
            return block[:, at[ps[0]]:at[ps[0]] + len(ps)]
        positions[lo:hi], rotations[lo:hi] = cols(_BASE), cols(_ROT)
        opacities[lo:hi] = cols(["opacity"])[:, 0]
        if surfels:
            two = cols(scale_names)
            scales[lo:hi] = np.concatenate([two, two.min(axis=1, keepdims=True) - SURFEL_THICKNESS_LOG], axis=1)
        else:
            scales[lo:hi] = cols(_SCALE)
        if not rgb_colour:
            sh_dc[lo:hi] = cols(_DC)
        for c in range(3 if k else 0):
            rest[lo:hi, :, c] = cols(rest_names[c * k:(c + 1) * k])
    if surfels:
        warnings.warn(GszInputWarning(
            f"{path}: {n:,} 2D Gaussian (surfel) vertices have scale_0 and scale_1 only: read as flat "
            "3D Gaussians, the third axis 1/100 of the smaller one"), stacklevel=2)
    cloud = GaussianCloud(
        positions=positions, scales=scales, rotations=rotations,
        opacities=opacities, sh_dc=sh_dc, sh_rest=rest, sh_degree=degree)
    if check_finite:
        for fname, props in (("positions", _BASE), ("scales", scale_names + ["scale_2"] * surfels),
                             ("rotations", _ROT), ("opacities", ["opacity"]),
                             ("sh_dc", _RGB if rgb_colour else _DC), ("sh_rest", rest_names)):
            arr = getattr(cloud, fname).reshape(n, len(props))     # not -1: n may be 0
            if all(np.isfinite(arr[s:s + 65536]).all() for s in range(0, n, 65536)):
                continue                      # in row steps: no N x 3K bool temporaries
            bad = ~np.isfinite(arr)
            if bad.any():
                r, c = np.argwhere(bad)[0]
                prop = props[c] if fname != "sh_rest" else _rest_prop_name(c, k)
                raise PlyFormatError(
                    f"property '{prop}' has {int(bad[:, c].sum())} non-finite values "
                    f"(first at vertex {int(r)})", path)
    return cloud


#: Vertex records converted at a time (15 MB of graphdeco SH-3 records).
READ_ROWS = 1 << 16


def _row_blocks(data, names: list, needed: list, path: str):
    """(lo, hi, [hi - lo, len(needed)] float32) blocks of the vertex records ``data`` (property
    ``names`` in file order), column j holding property ``needed[j]``.

    A file of float32 little-endian records that plyfile memory-mapped is read block by block
    through one buffer: pages of a mapping count as resident while it lives, and the whole file
    was held beside the cloud (1.5 GB at 6 M SH-3 Gaussians).  Other files are converted block
    by block from plyfile's records."""
    n, width = len(data), len(names)
    flat = all(data.dtype[p] == np.dtype("<f4") for p in names) and data.dtype.itemsize == 4 * width
    idx = [names.index(p) for p in needed]
    if flat and isinstance(data, np.memmap) and n:
        buf = np.empty(min(n, READ_ROWS) * width, "<f4")
        with open(path, "rb") as f:
            f.seek(data.offset)
            for lo in range(0, n, READ_ROWS):
                hi = min(n, lo + READ_ROWS)
                view = buf[:(hi - lo) * width]
                if f.readinto(memoryview(view).cast("B")) != view.nbytes:
                    raise PlyFormatError("the file ended inside the vertex data", path)
                yield lo, hi, view.reshape(hi - lo, width)[:, idx]
        return
    for lo in range(0, n, READ_ROWS):
        hi = min(n, lo + READ_ROWS)
        if flat:
            yield lo, hi, np.ascontiguousarray(data[lo:hi]).view("<f4").reshape(hi - lo, width)[:, idx]
            continue
        out = np.empty((hi - lo, len(needed)), np.float32)
        for j, p in enumerate(needed):
            try:
                out[:, j] = data[p][lo:hi]
            except (ValueError, TypeError) as e:
                raise PlyFormatError(f"property '{p}' cannot be read as float: {e}", path) from None
        yield lo, hi, out


def _rgb_dc(data, path: str) -> np.ndarray:
    """SH DC of a base colour stored as red/green/blue: integers over their type's range (uchar:
    0..255, as nerfstudio writes it), floats as 0..1 (or 0..255 when any exceeds 1)."""
    from .delivery import dc_of_colour
    chans = []
    for p in _RGB:
        v = np.asarray(data[p])
        if np.issubdtype(v.dtype, np.integer):
            chans.append(v.astype(np.float64) / max(1, np.iinfo(v.dtype).max))
        elif np.issubdtype(v.dtype, np.floating):
            chans.append(v.astype(np.float64))
        else:
            raise PlyFormatError(f"property '{p}' is not numeric", path)
    rgb = np.stack(chans, axis=1)
    floats = all(np.issubdtype(np.asarray(data[p]).dtype, np.floating) for p in _RGB)
    if floats and rgb.size and np.nanmax(rgb) > 1.0:    # float colours written as 0..255
        rgb = rgb / 255.0
    return dc_of_colour(rgb)


def _warn_undeclared_data(f, ply, path: str) -> None:
    """Warn (GszInputWarning) when data follow the elements the header declares: a header that
    claims fewer vertices than the file holds would otherwise drop the rest silently."""
    names = [el.name for el in ply.elements]
    n = len(ply["vertex"].data) if "vertex" in names else 0
    if ply.text:
        with open(path, "rb") as again:      # plyfile reads text through a wrapper of f
            raw = again.read()
        head = raw.find(b"end_header")
        lines = sum(1 for ln in raw[raw.index(b"\n", head) + 1:].splitlines() if ln.strip()) if head >= 0 else 0
        extra = lines - sum(len(el.data) for el in ply.elements)
        what = f"{extra:,} more data lines"
    else:
        extra = os.fstat(f.fileno()).st_size - f.tell()
        vertex_last = names and names[-1] == "vertex"
        item = ply["vertex"].data.dtype.itemsize if vertex_last else 0
        what = (f"{extra:,} more bytes ({extra // item:,} vertices' worth)" if item and extra % item == 0
                else f"{extra:,} more bytes")
    if extra > 0:
        warnings.warn(GszInputWarning(
            f"{path}: the header declares {n:,} vertices ('element vertex {n}') but the file holds {what} "
            "after them: ignored; fix the header if they belong to the scene"), stacklevel=3)


def _rest_prop_name(flat_col: int, k: int) -> str:
    # flat column of sh_rest[N, K, 3] reshaped to [N, 3K] -> coefficient k_i, channel c
    k_i, c = divmod(flat_col, 3)
    return f"f_rest_{c * k + k_i}"


def _graphdeco_names(k: int) -> list:
    return _BASE + _NORMALS + _DC + [f"f_rest_{i}" for i in range(3 * k)] + ["opacity"] + _SCALE + _ROT


def _graphdeco_header(n: int, names: list) -> bytes:
    header = ["ply", "format binary_little_endian 1.0", "comment written by gsz",
              f"element vertex {n}"] + [f"property float {p}" for p in names] + ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii")


def graphdeco_ply_bytes(num_gaussians: int, sh_degree: int) -> int:
    """Size of the graphdeco PLY (as :func:`write_ply` writes it) of a scene of this many
    Gaussians and SH degree: what a compression ratio of a non-PLY input is measured against."""
    names = _graphdeco_names(SH_REST_COUNT[sh_degree])
    return len(_graphdeco_header(num_gaussians, names)) + 4 * len(names) * num_gaussians


def cloud_to_ply_bytes(cloud: GaussianCloud) -> bytes:
    """Serialise a cloud as a binary little-endian graphdeco PLY (float32 everywhere)."""
    n = len(cloud)
    k = cloud.sh_rest.shape[1]
    names = _graphdeco_names(k)
    mat = np.empty((n, len(names)), dtype="<f4")
    mat[:, 0:3] = cloud.positions
    mat[:, 3:6] = 0.0
    mat[:, 6:9] = cloud.sh_dc
    o = 9
    if k:
        mat[:, o:o + 3 * k] = cloud.sh_rest.transpose(0, 2, 1).reshape(n, 3 * k)
    o += 3 * k
    mat[:, o] = cloud.opacities
    mat[:, o + 1:o + 4] = cloud.scales
    mat[:, o + 4:o + 8] = cloud.rotations
    return _graphdeco_header(n, names) + mat.tobytes()


def write_ply(cloud: GaussianCloud, path) -> None:
    """Write ``cloud`` as a graphdeco 3DGS PLY, atomically (no partial file on failure).

    ``read_ply(write_ply(c))`` reproduces ``c`` bit for bit.
    """
    cloud.validate(check_finite=False)
    atomic_write(path, cloud_to_ply_bytes(cloud))
