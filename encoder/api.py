"""The one-call Python API (spz-style): a cloud or a file in, .gsz bytes or a file out.

    import gsz
    data = gsz.encode(cloud, size="5MB")              # the size search; bytes of the .gsz
    gsz.encode_file("point_cloud.ply", "scene.gsz", ratio=12)
    cloud = gsz.load("scene.gsz")                     # numpy-only decode

``gsz.encode`` with no target encodes the fixed configuration of ``EncodeOptions``.
"""
from __future__ import annotations

from ..decoder.cloud import GaussianCloud


def encode_result(cloud: GaussianCloud, *, size=None, ratio=None, profile=None, options=None,
                  cameras=None, progress=None, source: str | None = None):
    """EncodeResult (data, decoded cloud, report) of ``cloud``: with one of ``size`` ("5MB",
    4_500_000), ``ratio`` (12 or "12x": of the cloud's graphdeco PLY size) or ``profile``
    ("medium"), the size search (``options``: SearchOptions); without one, the fixed
    configuration (``options``: EncodeOptions).  ``cameras``: train views (a list of Camera,
    or a cameras.json / COLMAP path), default generated ones."""
    from .progress import Progress
    from ..decoder.ply import graphdeco_ply_bytes
    from ..decoder.sizes import budget_from_args
    progress = progress or Progress(quiet=True)
    if isinstance(cameras, str):
        from ..evaluation.cameras import load_cameras
        cameras = load_cameras(cameras, cloud).train
    if size is None and ratio is None and profile is None:
        from .pipeline import EncodeOptions, encode as encode_fixed
        opts = (options or EncodeOptions()).validate()
        return encode_fixed(cloud, opts, cameras=cameras, progress=progress, source=source)
    from .search import SearchOptions, encode_to_budget
    target = budget_from_args(size=size, ratio=ratio, profile=profile,
                              ply_bytes=graphdeco_ply_bytes(len(cloud), cloud.sh_degree))
    return encode_to_budget(cloud, target, options=options or SearchOptions(), cameras=cameras,
                            progress=progress, source=source)


def encode(cloud: GaussianCloud, *, size=None, ratio=None, profile=None, options=None,
           cameras=None) -> bytes:
    """The .gsz bytes of ``cloud`` (see :func:`encode_result`)."""
    return encode_result(cloud, size=size, ratio=ratio, profile=profile, options=options,
                         cameras=cameras).data


def encode_file(src, dst, *, size=None, ratio=None, profile=None, options=None, cameras=None):
    """Encode the scene file ``src`` (any format :func:`gsz.load` reads) to the .gsz ``dst``,
    written atomically; ``ratio``/``profile`` measure against ``src`` when it is a graphdeco
    PLY, else against its scene's PLY size.  Returns the EncodeResult."""
    import os
    from ..decoder.formats import load
    from ..decoder.io_util import atomic_write
    cloud = load(src)
    ply_ratio = ratio is not None or profile is not None
    if ply_ratio and str(src).lower().endswith(".ply"):
        from ..decoder.sizes import budget_from_args
        size = budget_from_args(ratio=ratio, profile=profile, ply_bytes=os.path.getsize(src))
        ratio = profile = None
    res = encode_result(cloud, size=size, ratio=ratio, profile=profile, options=options,
                        cameras=cameras, source=str(src))
    atomic_write(dst, res.data)
    return res
