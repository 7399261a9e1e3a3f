"""Exception types of gsz.

Every error a user can cause with bad input is a :class:`GszError` whose message names the
file (when there is one) and the problem.  Callers that embed the decoder catch this one type.
"""
from __future__ import annotations


class GszError(Exception):
    """Base class of every error gsz raises on bad input."""

    def __init__(self, message: str, path: str | None = None):
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)


class GszUsageError(GszError, ValueError):
    """A bad option value or combination on a command line (or the equivalent argument of the
    API): the tools exit with status 2 for it, as argparse does, and 1 for every other error."""


class PlyFormatError(GszError, ValueError):
    """A PLY file is not a readable 3DGS (graphdeco layout) point cloud."""


class GszFormatError(GszError, ValueError):
    """A .gsz bitstream is corrupt, truncated, hostile or of an unsupported version."""


class GszLimitError(GszFormatError):
    """A .gsz file declares more Gaussians than the decoder's limit allows: a decompression
    bomb, or a trusted file that needs a larger ``max_gaussians`` (GSZ.md §11)."""


class GszTruncatedError(GszFormatError):
    """A .gsz file ends before its last chunk (a download cut short, a partial copy).
    ``decode(..., partial=True)`` decodes the complete layers of such a file instead."""


class GltfFormatError(GszError, ValueError):
    """A .gltf/.glb file is not a readable ``KHR_gaussian_splatting`` scene (its container,
    JSON, accessors or splat attributes are malformed or use a feature gsz does not read)."""


class GszOutputError(GszError, OSError):
    """An output file cannot be written (unwritable or missing folder, a directory or device in
    its place, the input itself, a full disk); also an OSError, the failure it replaces."""


class CloudValidationError(GszError, ValueError):
    """A GaussianCloud's arrays are inconsistent (shapes, dtypes, non-finite values)."""


class CameraFormatError(GszError, ValueError):
    """A cameras.json or COLMAP model cannot be read."""


class GszTruncatedWarning(UserWarning):
    """A .gsz stream ended early: only its complete layers were decoded (the documented
    truncation signal of :class:`gsz.decoder.stream.StreamDecoder` and ``decode(partial=True)``)."""


class GszInputWarning(UserWarning):
    """An input scene held something gsz fixed or ignored to encode the rest well (an absurd
    value clamped, a far-away Gaussian dropped, vertices after the ones a PLY header declares);
    the message names the file, the property and the count."""


class SceneFormatError(GszError, ValueError):
    """A delivery-format scene file (.spz, .splat, .ksplat, .sog) is truncated, corrupt or uses
    a feature gsz does not read; the message names the file, the format and the problem.  Each
    format has its own subclass (a PlayCanvas compressed PLY is a :class:`PlyFormatError`)."""


class SpzFormatError(SceneFormatError):
    """An .spz file (Niantic/Adobe SPZ, versions 1-4) cannot be read."""


class SplatFormatError(SceneFormatError):
    """An antimatter15 .splat file (32-byte rows) cannot be read."""


class KsplatFormatError(SceneFormatError):
    """A mkkellogg GaussianSplats3D .ksplat file cannot be read."""


class SogFormatError(SceneFormatError):
    """A PlayCanvas SOG scene (.sog zip bundle or its meta.json) cannot be read."""


class MissingExtraError(GszError, ImportError):
    """Reading or writing a file needs an optional library that is not installed; the message
    names the pip extra that brings it."""
