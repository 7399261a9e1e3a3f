"""Scene files by content: ``load(path)`` reads any scene format below into one
:class:`GaussianCloud` (graphdeco conventions: RDF frame, log scales, logit opacities,
(w, x, y, z) quaternions, SH coefficient-major); ``save(cloud, path)`` writes a PLY, .spz,
.glb or .gltf by the path's extension.

========================= ============================================= ========================
format                    told by                                       reader
========================= ============================================= ========================
graphdeco 3DGS PLY        ``ply`` magic                                 :mod:`.ply`
  nerfstudio/gsplat "rgb" ``red green blue`` instead of ``f_dc_*``      :mod:`.ply`
  2DGS surfels            ``scale_0 scale_1`` only                      :mod:`.ply`
PlayCanvas compressed PLY ``chunk`` element, ``packed_*`` properties    :mod:`.compressed_ply`
.gsz                      its 8-byte magic                              :mod:`.decode`
glTF (.glb / .gltf)       ``glTF`` magic / a JSON object with no
                          ``means``                                     :mod:`.gltf` (gltf extra)
SPZ (.spz) v2, v3, v4     gzip holding ``NGSP`` / ``NGSP``              :mod:`.spz`
PlayCanvas SOG            a zip holding meta.json (.sog) / a JSON
                          object with ``means`` and ``quats``
                          (meta.json beside its WebP textures)          :mod:`.sog` (formats extra)
GaussianSplats3D .ksplat  a header consistent with the file's size     :mod:`.ksplat`
antimatter15 .splat       size a multiple of 32, finite positions and
                          positive scales in its first rows             :mod:`.splat`
========================= ============================================= ========================

The kind of an input is told by its first bytes (and, for the two formats without a magic
number, .ksplat and .splat, by its size), never by its name.  Each format's frame and value
conventions are converted to graphdeco's (see each reader).  A file that is none of them, or a
truncated or corrupt one, raises a :class:`GszError` subclass naming the file and the problem.
numpy (+ zstandard) only, except that plain glTF needs pygltflib (the ``gltf`` extra) and SOG
needs Pillow with WebP (the ``formats`` extra), imported when such a file is met.
"""
from __future__ import annotations

import json
import os

from .cloud import GaussianCloud
from .container import MAGIC
from .errors import GszError
from .glb import is_glb
from .io_util import check_input_file

PLY, GSZ, GLB, GLTF, SPZ, SOG, KSPLAT, SPLAT = "ply", "gsz", "glb", "gltf", "spz", "sog", "ksplat", "splat"
#: what a file of each kind is called in messages
KIND_NAMES = {PLY: "3DGS PLY", GSZ: ".gsz", GLB: "glTF binary (.glb)", GLTF: "glTF JSON (.gltf)",
              SPZ: "SPZ (.spz)", SOG: "PlayCanvas SOG (.sog / meta.json)", KSPLAT: ".ksplat",
              SPLAT: "antimatter15 .splat"}
#: bytes read to tell a file's kind: a .ksplat's header and first section header, a gzip's start
HEAD_BYTES = 4096 + 1024
#: a JSON file larger than this is taken for glTF without parsing it (a SOG meta.json is ~10 kB)
_SOG_META_MAX = 1 << 20
#: what save() writes, by extension
SAVE_EXTENSIONS = (".ply", ".spz", ".glb", ".gltf")


def sniff(prefix, size: int | None = None) -> str | None:
    """The kind of a file whose first bytes are ``prefix`` (up to :data:`HEAD_BYTES` of them)
    and whose size is ``size`` (needed for .ksplat and .splat, which have no magic number).
    A JSON object is reported as GLTF here; :func:`sniff_file` tells a SOG meta.json apart."""
    head = bytes(prefix[:HEAD_BYTES])
    if head[:8] == MAGIC:
        return GSZ
    if is_glb(head):
        return GLB
    if head[:4] in (b"ply\n", b"ply\r"):
        return PLY
    from .spz import is_spz
    if is_spz(head):
        return SPZ
    from .sog import is_sog_zip
    if is_sog_zip(head):
        return SOG
    if _looks_like_json(head):
        return GLTF
    if size is None:
        return None
    from .ksplat import ksplat_problem
    if ksplat_problem(head, size) is None:
        return KSPLAT
    from .splat import splat_problem
    if splat_problem(head, size) is None:
        return SPLAT
    return None


def _looks_like_json(head: bytes) -> bool:
    """A JSON object's start: ``{`` after an optional UTF-8 byte-order mark and whitespace, and
    no control bytes in the first 256 (binary data, a .splat's floats, nearly always has some)."""
    text = head[3:] if head[:3] == b"\xef\xbb\xbf" else head
    if text.lstrip(b" \t\r\n")[:1] != b"{":
        return False
    return not any(b < 0x20 and b not in (9, 10, 13) for b in text[:256])


def sniff_file(path, error=GszError) -> str:
    """The kind of the file at ``path`` (checked as an input first); ``error`` naming the file
    when it is none gsz reads."""
    path = os.fspath(path)
    size = check_input_file(path, error)
    try:
        with open(path, "rb") as f:
            head = f.read(HEAD_BYTES)
    except OSError as e:
        raise error(f"cannot read: {e.strerror or e}", path) from None
    kind = sniff(head, size)
    if kind == GLTF and size <= _SOG_META_MAX:
        json_kind = _json_kind(path)
        if json_kind == "lod":
            raise error("is a streamed SOG (lod-meta.json), which gsz does not read: convert it to a .sog "
                        "or PLY with splat-transform first", path)
        if json_kind == SOG:
            return SOG
    if kind is None:
        raise error(_not_a_scene(path, head, size), path)
    return kind


def _json_kind(path: str) -> str | None:
    """SOG for a SOG meta.json, "lod" for a streamed SOG's lod-meta.json, else None (glTF, or
    JSON the glTF reader will name the problem of)."""
    from .sog import is_sog_meta
    try:
        with open(path, "rb") as f:
            doc = json.loads(f.read().decode("utf-8-sig"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if is_sog_meta(doc):
        return SOG
    if isinstance(doc, dict) and "lodLevels" in doc and "tree" in doc:
        return "lod"
    return None


def _not_a_scene(path: str, head: bytes, size: int) -> str:
    """The message for a file of no known kind, with the .splat/.ksplat reason when its name
    says it meant to be one (the name is a hint for the message only, never for the kind)."""
    msg = ("is not a scene file gsz reads: not a 3DGS PLY, .gsz, .glb or .gltf, .spz, .sog or .ksplat "
           "by its first bytes, nor a .splat by its size and values")
    ext = os.path.splitext(path)[1].lower()
    if head[:2] == b"\x1f\x8b":
        return msg + " (it is gzip data, but not an SPZ's)"
    if ext == ".splat":
        from .splat import splat_problem
        return msg + f" ({splat_problem(head, size)})"
    if ext == ".ksplat":
        from .ksplat import ksplat_problem
        return msg + f" ({ksplat_problem(head, size)})"
    return msg


def is_compressed(path) -> bool:
    """True for a .gsz file or a .glb carrying one (what streaming and layer prefixes need);
    False for anything else, including files that cannot be read."""
    try:
        kind = sniff_file(path)
        if kind == GSZ:
            return True
        if kind != GLB:
            return False
        from .glb import gsz_location, parse_glb
        with open(os.fspath(path), "rb") as f:
            head = f.read(1 << 20)              # the JSON of a splat .glb is a few kB
        gsz_location(parse_glb(head, partial=True))
        return True
    except GszError:
        return False


def load(path, *, max_gaussians: int | None = None) -> GaussianCloud:
    """The scene in ``path``, whatever its kind (told by content, see the module table): a
    graphdeco cloud (RDF frame, log scales, logits, (w, x, y, z) quaternions).  A .gsz, or a .glb
    carrying one, is decoded within ``max_gaussians`` (bit-identical to
    :func:`gsz.decoder.decode`, unless the glTF node holding it has a transform, which is baked
    in); an .spz's header is held to the same limit; a plain glTF is converted
    (:func:`gsz.decoder.gltf.read_gltf`)."""
    path = os.fspath(path)
    kind = sniff_file(path)
    if kind == PLY:
        from .ply import read_ply
        return read_ply(path)
    if kind == SPZ:
        from .spz import read_spz
        return read_spz(path, max_gaussians=max_gaussians)
    if kind == SOG:
        from .sog import read_sog
        return read_sog(path)
    if kind == KSPLAT:
        from .ksplat import read_ksplat
        return read_ksplat(path)
    if kind == SPLAT:
        from .splat import read_splat
        return read_splat(path)
    if kind == GSZ or (kind == GLB and _plain_gsz_glb(path)):
        from .decode import decode
        return decode(path, max_gaussians=max_gaussians)   # no glTF library needed
    from .gltf import read_gltf
    return read_gltf(path)


def _plain_gsz_glb(path: str) -> bool:
    """True for a .glb that is one untransformed gsz primitive (as gsz-encode writes them)."""
    from .glb import is_plain_gsz_scene, parse_glb
    with open(path, "rb") as f:
        head = f.read(1 << 20)                # the JSON of a splat .glb is a few kB
    try:
        return is_plain_gsz_scene(parse_glb(head, partial=True).doc)
    except GszError:
        return False                          # the glTF reader gives the real error


def save(cloud: GaussianCloud, path, *, spz_version: int = 3) -> None:
    """Write ``cloud`` by the extension of ``path``: .ply (graphdeco PLY), .spz (SPZ version
    ``spz_version``, 3 or 4, RDF frame as splat-transform writes it, see :mod:`.spz`), .glb or
    .gltf (plain ``KHR_gaussian_splatting``), atomically.  (A .gsz needs the encoder:
    ``gsz-encode`` or ``gsz.encoder.pipeline.encode``.)"""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ply":
        from .ply import write_ply
        return write_ply(cloud, path)
    if ext == ".spz":
        from .spz import write_spz
        return write_spz(cloud, path, version=spz_version)
    if ext in (".glb", ".gltf"):
        from .gltf import write_gltf
        return write_gltf(cloud, path)
    raise GszError("save() writes .ply, .spz, .glb or .gltf (by the extension); a .gsz needs the encoder "
                   "(gsz-encode, or gsz.encoder.pipeline.encode)", path)
