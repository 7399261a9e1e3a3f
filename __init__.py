"""gsz: size-aware compression of 3D Gaussian Splatting scenes.

The top-level namespace re-exports the numpy-only core (no torch import here):

    import gsz
    cloud = gsz.read_ply("point_cloud.ply")
    gsz.write_ply(cloud, "copy.ply")
    cloud = gsz.load("scene.spz")          # PLY (and its variants), .gsz, .glb, .gltf, .spz, .sog,
                                           # .ksplat, .splat, told by content
    gsz.save(cloud, "scene.spz")           # .ply, .spz, or plain KHR_gaussian_splatting .glb/.gltf

Sub-packages: ``gsz.decoder`` (numpy-only bitstream reader), ``gsz.encoder`` (torch CPU
encoder, renderer, metrics), ``gsz.kernels`` (CUDA/CPU quantisation kernels), ``gsz.viewer``.
"""
from .decoder.cloud import GaussianCloud
from .decoder.errors import GltfFormatError, GszError, PlyFormatError
from .decoder.formats import load, save
from .decoder.gltf import read_gltf, write_gltf
from .decoder.ply import read_ply, write_ply

#: the one place the version is written (pyproject.toml reads it; META records "gsz <version>")
__version__ = "0.1.0"
__all__ = ["GaussianCloud", "GszError", "PlyFormatError", "GltfFormatError", "read_ply", "write_ply",
           "load", "save", "read_gltf", "write_gltf", "__version__"]
