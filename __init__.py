"""gsz: size-aware compression of 3D Gaussian Splatting scenes.

The top-level namespace re-exports the numpy-only core (no torch import here):

    import gsz
    cloud = gsz.read_ply("point_cloud.ply")
    gsz.write_ply(cloud, "copy.ply")
    cloud = gsz.load("scene.spz")          # PLY (and its variants), .gsz, .glb, .gltf, .spz, .sog,
                                           # .ksplat, .splat, told by content
    gsz.save(cloud, "scene.spz")           # .ply, .spz, or plain KHR_gaussian_splatting .glb/.gltf
    data = gsz.encode(cloud, size="5MB")   # the size search (needs gsz[encoder]: torch)
    gsz.encode_file("point_cloud.ply", "scene.gsz", ratio=12)
    rub = gsz.convert_frame(cloud, "RDF", "RUB")   # axis conventions (graphdeco PLY <-> OpenGL)

Sub-packages: ``gsz.decoder`` (numpy-only bitstream reader), ``gsz.encoder`` (torch CPU
encoder), ``gsz.evaluation`` (cameras, CPU renderer, metrics), ``gsz.kernels`` (CUDA/CPU
quantisation kernels), ``gsz.viewer``.
"""
from .decoder.cloud import GaussianCloud
from .decoder.errors import GltfFormatError, GszError, PlyFormatError
from .decoder.formats import load, save
from .decoder.gltf import read_gltf, write_gltf
from .decoder.frames import convert_frame
from .decoder.ply import read_ply, write_ply


def encode(cloud, *, size=None, ratio=None, profile=None, options=None, cameras=None) -> bytes:
    """The .gsz bytes of ``cloud`` (:func:`gsz.encoder.api.encode`; imports torch)."""
    from .encoder.api import encode as _encode
    return _encode(cloud, size=size, ratio=ratio, profile=profile, options=options, cameras=cameras)


def encode_file(src, dst, *, size=None, ratio=None, profile=None, options=None, cameras=None):
    """Encode the scene file ``src`` to the .gsz ``dst`` (:func:`gsz.encoder.api.encode_file`)."""
    from .encoder.api import encode_file as _encode_file
    return _encode_file(src, dst, size=size, ratio=ratio, profile=profile, options=options, cameras=cameras)


#: the one place the version is written (pyproject.toml reads it; META records "gsz <version>")
__version__ = "0.1.0"
__all__ = ["GaussianCloud", "GszError", "PlyFormatError", "GltfFormatError", "read_ply", "write_ply",
           "load", "save", "read_gltf", "write_gltf", "encode", "encode_file", "convert_frame", "__version__"]
