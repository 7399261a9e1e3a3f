"""Read .ksplat files, the SplatBuffer of mkkellogg's GaussianSplats3D (numpy only).

Layout (little-endian): a 4096-byte header (version 0.1+, section count, Gaussian count,
compression level 0-2, the SH range of level 2), one 1024-byte header per section, then each
section: the sizes of its partly filled buckets (u32), its bucket centres (3 x f32), and its
rows.  A row holds the centre (level 0: 3 x f32; 1-2: 3 x u16 offsets from the bucket centre),
the linear scales and the unit quaternion (w, x, y, z) (level 0: f32; 1-2: f16), colour and
alpha bytes, and the SH of degree 1-2 (level 0: f32, 1: f16, 2: bytes over the header's range)
in the order band 1 R G B (3 each), band 2 R G B (5 each).  PLY (RDF) frame.

A .ksplat has no magic number: a file is taken for one when its header and first section
header are consistent with each other and with its size (:func:`ksplat_problem`).
"""
from __future__ import annotations

import os
import struct

import numpy as np

from .cloud import GaussianCloud
from .delivery import dc_of_colour_bytes, logit_of_alpha_bytes, unit_quaternions
from .io_util import read_all
from .errors import KsplatFormatError

HEADER, SECTION_HEADER = 4096, 1024
#: bytes of centre, scale, rotation and colour per row, and of one SH value, by compression level
_LEVELS = {0: (12, 12, 16, 4, 4), 1: (6, 6, 8, 4, 2), 2: (6, 6, 8, 4, 1)}
_SH_VALUES = {0: 0, 1: 9, 2: 24}
#: the SH range of a level-2 file whose header leaves it zero (GaussianSplats3D's default)
_DEFAULT_SH_RANGE = (-1.5, 1.5)
#: log of the smallest f16 (2^-24): what a scale that rounded to zero in half precision reads as
_F16_ZERO_LOG_SCALE = float(np.log(2.0 ** -24))
#: more sections than this is no real file (GaussianSplats3D writes a handful)
MAX_SECTIONS = 1 << 16


def _row_bytes(level: int, degree: int) -> int:
    c, s, r, col, sh = _LEVELS[level]
    return c + s + r + col + _SH_VALUES[degree] * sh


def _main_header(data):
    major, minor = data[0], data[1]
    max_sections, sections, max_splats, splats = struct.unpack_from("<4I", data, 4)
    level = struct.unpack_from("<H", data, 20)[0]
    sh_min, sh_max = struct.unpack_from("<2f", data, 36)
    return major, minor, max_sections, sections, max_splats, splats, level, sh_min, sh_max


def _section(data, i, level):
    o = HEADER + i * SECTION_HEADER
    count, max_count, bucket_size, buckets = struct.unpack_from("<4I", data, o)
    block = struct.unpack_from("<f", data, o + 16)[0]
    bucket_bytes = struct.unpack_from("<H", data, o + 20)[0]
    scale_range = struct.unpack_from("<I", data, o + 24)[0] or (1 if level == 0 else 32767)
    full, partial = struct.unpack_from("<2I", data, o + 32)
    degree = struct.unpack_from("<H", data, o + 40)[0]
    return dict(count=count, max_count=max_count, bucket_size=bucket_size, buckets=buckets, block=block,
                bucket_bytes=bucket_bytes, range=scale_range, full=full, partial=partial, degree=degree)


def ksplat_problem(head: bytes, size: int) -> str | None:
    """Why a file of ``size`` bytes starting with ``head`` (at least 5 kB when it has them) is
    not a .ksplat, or None when its headers fit one."""
    if size < HEADER + SECTION_HEADER or len(head) < HEADER + SECTION_HEADER:
        return "shorter than a .ksplat's 4096-byte header and first section header"
    major, minor, max_sections, sections, max_splats, splats, level, _, _ = _main_header(head)
    if major != 0 or minor < 1 or head[2:4] != b"\0\0":
        return f"version bytes {major}.{minor} are not a .ksplat's 0.1+"
    if level not in _LEVELS:
        return f"compression level {level} is not 0, 1 or 2"
    if not 1 <= max_sections <= MAX_SECTIONS or sections > max_sections or splats > max_splats:
        return "section and Gaussian counts of the header are inconsistent"
    if HEADER + max_sections * SECTION_HEADER > size:
        return f"{max_sections:,} section headers do not fit its {size:,} bytes"
    s = _section(head, 0, level)
    if s["degree"] not in _SH_VALUES or s["count"] > s["max_count"]:
        return "its first section header is not a .ksplat's"
    return None


def read_ksplat(path) -> GaussianCloud:
    """The scene in the .ksplat file ``path`` as a graphdeco cloud; :class:`KsplatFormatError`
    naming the file and the problem when it is truncated or inconsistent."""
    path = os.fspath(path)
    data = read_all(path, KsplatFormatError)

    def fail(message):
        return KsplatFormatError(message, path)

    problem = ksplat_problem(data, len(data))
    if problem:
        raise fail(f"not a .ksplat: {problem}")
    _, _, max_sections, _, _, splats, level, sh_min, sh_max = _main_header(data)
    if level == 2 and not (sh_min or sh_max):
        sh_min, sh_max = _DEFAULT_SH_RANGE
    sections = [_section(data, i, level) for i in range(max_sections)]
    degree = max((s["degree"] for s in sections if s["count"]), default=0)
    for s in sections:
        if s["degree"] not in _SH_VALUES:
            raise fail(f"a section declares SH degree {s['degree']}; .ksplat holds 0-2")
    total = sum(s["count"] for s in sections)
    if total != splats:
        raise fail(f"its sections hold {total:,} Gaussians but its header declares {splats:,}")
    parts = []
    o = HEADER + max_sections * SECTION_HEADER
    for i, s in enumerate(sections):
        o, cloud = _read_section(data, o, s, level, degree, sh_min, sh_max, fail, i)
        if cloud is not None:
            parts.append(cloud)
    k = {0: 0, 1: 3, 2: 8}[degree]
    if not parts:
        return GaussianCloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0),
                             np.zeros((0, 3)), np.zeros((0, k, 3)), degree)
    cat = [np.concatenate([p[j] for p in parts]) for j in range(6)]
    return GaussianCloud(*cat, degree)


def _read_section(data, o, s, level, degree, sh_min, sh_max, fail, index):
    """(offset after section ``index``, its arrays or None when it is empty)."""
    c_bytes, s_bytes, r_bytes, col_bytes, sh_bytes = _LEVELS[level]
    sec_degree = s["degree"]
    row = _row_bytes(level, sec_degree)
    bucket_meta = 4 * s["partial"]
    bucket_store = s["bucket_bytes"] * s["buckets"] + bucket_meta
    end = o + bucket_store + row * s["max_count"]
    if end > len(data):
        raise fail(f"truncated: section {index} ends at byte {end:,} of a {len(data):,}-byte file")
    n = s["count"]
    if n == 0:
        return end, None
    rows = np.frombuffer(data, np.uint8, n * row, o + bucket_store).reshape(n, row)

    def field(start, nbytes, dtype):
        return np.ascontiguousarray(rows[:, start:start + nbytes]).view(dtype)

    if level == 0:
        positions = field(0, 12, "<f4").astype(np.float64)
        lin_scales = field(12, 12, "<f4").astype(np.float64)
        quats = field(24, 16, "<f4").astype(np.float64)
    else:
        if s["bucket_bytes"] != 12:
            raise fail(f"section {index} stores {s['bucket_bytes']}-byte buckets, not 3 floats")
        if s["full"] + s["partial"] > s["buckets"]:
            raise fail(f"section {index} has more full and partial buckets than buckets")
        partial = np.frombuffer(data, "<u4", s["partial"], o).astype(np.int64)
        centres = np.frombuffer(data, "<f4", 3 * s["buckets"], o + bucket_meta).reshape(-1, 3).astype(np.float64)
        sizes = np.concatenate([np.full(s["full"], s["bucket_size"], np.int64), partial])
        if sizes.sum() < n:
            raise fail(f"section {index}: its buckets hold {int(sizes.sum()):,} Gaussians, not {n:,}")
        bucket = np.repeat(np.arange(len(sizes)), sizes)[:n]
        offsets = field(0, 6, "<u2").astype(np.float64) - s["range"]
        positions = offsets * (s["block"] / 2.0 / s["range"]) + centres[bucket]
        lin_scales = field(6, 6, "<f2").astype(np.float64)
        quats = field(12, 8, "<f2").astype(np.float64)
    col = c_bytes + s_bytes + r_bytes
    rgba = rows[:, col:col + 4]
    with np.errstate(divide="ignore"):
        scales = np.where(lin_scales > 0, np.log(np.where(lin_scales > 0, lin_scales, 1.0)), _F16_ZERO_LOG_SCALE)
    k_out = {0: 0, 1: 3, 2: 8}[degree]
    rest = np.zeros((n, k_out, 3), np.float32)
    if sec_degree:
        v = _SH_VALUES[sec_degree]
        start = col + col_bytes
        if level == 0:
            sh = field(start, 4 * v, "<f4").astype(np.float64)
        elif level == 1:
            sh = field(start, 2 * v, "<f2").astype(np.float64)
        else:
            sh = sh_min + rows[:, start:start + v].astype(np.float64) / 255.0 * (sh_max - sh_min)
        rest[:, 0:3, :] = sh[:, 0:9].reshape(n, 3, 3).transpose(0, 2, 1)      # band 1: R G B x 3
        if sec_degree == 2:
            rest[:, 3:8, :] = sh[:, 9:24].reshape(n, 3, 5).transpose(0, 2, 1)  # band 2: R G B x 5
    if not (np.isfinite(positions).all() and np.isfinite(scales).all() and np.isfinite(quats).all()
            and np.isfinite(rest).all()):
        raise fail(f"corrupt: section {index} holds non-finite values")
    return end, (positions.astype(np.float32), scales.astype(np.float32), unit_quaternions(quats),
                 logit_of_alpha_bytes(rgba[:, 3]), dc_of_colour_bytes(rgba[:, :3]), rest)
