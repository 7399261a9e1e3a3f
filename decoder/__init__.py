"""gsz.decoder: the numpy-only core (data model, PLY I/O, .gsz bitstream reader).

Importing this package never imports torch.
"""
from .cloud import GaussianCloud, sh_rest_count
from .errors import CameraFormatError, CloudValidationError, GszError, GszFormatError, PlyFormatError
from .ply import read_ply, write_ply

__all__ = ["GaussianCloud", "sh_rest_count", "GszError", "GszFormatError", "PlyFormatError",
           "CloudValidationError", "CameraFormatError", "read_ply", "write_ply"]
from .decode import decode, inspect  # noqa: E402

__all__ += ["decode", "inspect"]
