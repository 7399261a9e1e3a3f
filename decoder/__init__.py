"""gsz.decoder: the numpy-only core (data model, PLY I/O, .gsz bitstream reader, size budgets).

Importing this package never imports torch.  ``native_available()`` says whether the optional C
accelerator (``decoder/csrc/``, bit-identical output) is built and enabled; ``GSZ_NATIVE=0``
in the environment forces the NumPy reference path; ``decoder_path()`` is "native" or "numpy".
"""
from .cloud import GaussianCloud, sh_rest_count
from .errors import (CameraFormatError, CloudValidationError, GltfFormatError, GszError, GszFormatError,
                     GszInputWarning, GszLimitError, GszOutputError, GszTruncatedError, GszTruncatedWarning,
                     KsplatFormatError, MissingExtraError, PlyFormatError, SceneFormatError, SogFormatError,
                     SplatFormatError, SpzFormatError)
from .ply import read_ply, write_ply

__all__ = ["GaussianCloud", "sh_rest_count", "GszError", "GszFormatError", "PlyFormatError",
           "CloudValidationError", "CameraFormatError", "GltfFormatError", "GszLimitError", "GszTruncatedError",
           "GszTruncatedWarning", "GszInputWarning", "GszOutputError", "SceneFormatError", "SpzFormatError",
           "SplatFormatError", "KsplatFormatError", "SogFormatError", "MissingExtraError",
           "read_ply", "write_ply"]
from .decode import decode, inspect  # noqa: E402
from .formats import load, save  # noqa: E402
from .native import active_path as decoder_path, native_available  # noqa: E402
from .stream import StreamDecoder, StreamResult, StreamUpdate, iter_layers  # noqa: E402

__all__ += ["decode", "inspect", "load", "save", "StreamDecoder", "StreamResult", "StreamUpdate", "iter_layers",
            "native_available", "decoder_path"]
