"""Scene files by content: ``load(path)`` reads a 3DGS PLY, a .gsz, a .glb (plain
``KHR_gaussian_splatting`` or carrying a .gsz) or a .gltf; ``save(cloud, path)`` writes a PLY,
.glb or .gltf by the path's extension.

The kind of an input is told by its first bytes, never by its name: ``ply`` (PLY), the .gsz
magic, ``glTF`` (GLB), or a JSON object (glTF JSON; a UTF-8 byte-order mark and whitespace may
precede it).  numpy only, except that plain glTF needs pygltflib (the ``gltf`` extra), imported
when such a file is met.
"""
from __future__ import annotations

import os

from .cloud import GaussianCloud
from .container import MAGIC
from .errors import GszError
from .glb import is_glb
from .io_util import check_input_file

PLY, GSZ, GLB, GLTF = "ply", "gsz", "glb", "gltf"
#: what a file of each kind is called in messages
KIND_NAMES = {PLY: "3DGS PLY", GSZ: ".gsz", GLB: "glTF binary (.glb)", GLTF: "glTF JSON (.gltf)"}


def sniff(prefix) -> str | None:
    """The kind of a file whose first bytes (at least 8 when it has them) are ``prefix``."""
    head = bytes(prefix[:64])
    if head[:8] == MAGIC:
        return GSZ
    if is_glb(head):
        return GLB
    if head[:4] in (b"ply\n", b"ply\r"):
        return PLY
    text = head[3:] if head[:3] == b"\xef\xbb\xbf" else head
    if text.lstrip(b" \t\r\n")[:1] == b"{":
        return GLTF
    return None


def sniff_file(path, error=GszError) -> str:
    """The kind of the file at ``path`` (checked as an input first); ``error`` naming the file
    when it is none gsz reads."""
    path = os.fspath(path)
    check_input_file(path, error)
    try:
        with open(path, "rb") as f:
            head = f.read(64)
    except OSError as e:
        raise error(f"cannot read: {e.strerror or e}", path) from None
    kind = sniff(head)
    if kind is None:
        raise error("is not a 3DGS PLY, .gsz, .glb or .gltf file (its first bytes are none of theirs)", path)
    return kind


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
    """The scene in ``path``, whatever its kind (told by content): a graphdeco cloud (RDF frame,
    log scales, logits, (w, x, y, z) quaternions).  A .gsz, or a .glb carrying one, is decoded
    within ``max_gaussians`` (bit-identical to :func:`gsz.decoder.decode`, unless the glTF node holding it has a
    transform, which is baked in); a plain glTF is converted (:func:`gsz.decoder.gltf.read_gltf`)."""
    path = os.fspath(path)
    kind = sniff_file(path)
    if kind == PLY:
        from .ply import read_ply
        return read_ply(path)
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


def save(cloud: GaussianCloud, path) -> None:
    """Write ``cloud`` by the extension of ``path``: .ply (graphdeco PLY), .glb or .gltf (plain
    ``KHR_gaussian_splatting``), atomically.  (A .gsz needs the encoder: ``gsz-encode``.)"""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ply":
        from .ply import write_ply
        return write_ply(cloud, path)
    if ext in (".glb", ".gltf"):
        from .gltf import write_gltf
        return write_gltf(cloud, path)
    raise GszError("save() writes .ply, .glb or .gltf (by the extension); a .gsz needs the encoder "
                   "(gsz-encode, or gsz.encoder.pipeline.encode)", path)
