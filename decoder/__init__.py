"""gsz.decoder: the numpy-only core (data model, PLY I/O, .gsz bitstream reader).

Importing this package never imports torch.
"""
from .cloud import GaussianCloud, sh_rest_count
from .errors import (CameraFormatError, CloudValidationError, GszError, GszFormatError, GszTruncatedError,
                     GszTruncatedWarning,
                     PlyFormatError)
from .ply import read_ply, write_ply

__all__ = ["GaussianCloud", "sh_rest_count", "GszError", "GszFormatError", "PlyFormatError",
           "CloudValidationError", "CameraFormatError", "GszTruncatedError", "GszTruncatedWarning", "read_ply", "write_ply"]
from .decode import decode, inspect  # noqa: E402
from .stream import StreamDecoder, StreamResult, StreamUpdate, iter_layers  # noqa: E402

__all__ += ["decode", "inspect", "StreamDecoder", "StreamResult", "StreamUpdate", "iter_layers"]
