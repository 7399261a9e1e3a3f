"""Build hook for the optional C accelerator ``gsz.decoder._native`` (decoder/csrc/).

Everything else about the package is declared in pyproject.toml.  The extension is optional:
when no C compiler is available the build prints a warning, the install still succeeds and gsz
decodes with its NumPy reference path (``gsz.decoder.native_available()`` is then False).
"""
from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# one C file per stage plus the module glue (decoder/csrc/gsz_common.h describes the layout)
NATIVE_SOURCES = [f"decoder/csrc/{name}.c" for name in (
    "common", "octree_walk", "octree_decode", "octree_encode", "rans_decode", "rans_encode",
    "model_set", "raht", "assemble", "rate", "module")]


class BuildExt(build_ext):
    """Adds the flags the bit-exactness of the native path relies on, per compiler family."""

    def build_extensions(self):
        if self.compiler.compiler_type == "msvc":
            # /fp:precise forbids contracting a*b+c into an FMA (inverse RAHT must round like NumPy)
            args = ["/O2", "/fp:precise"]
        else:
            # no FMA contraction and no fast-math: the float64 butterflies must round exactly as
            # NumPy's separate multiplies and adds
            args = ["-O2", "-ffp-contract=off", "-fno-fast-math"]
        for ext in self.extensions:
            ext.extra_compile_args = args + list(ext.extra_compile_args or [])
        super().build_extensions()


setup(
    ext_modules=[Extension("gsz.decoder._native", sources=NATIVE_SOURCES,
                           include_dirs=["decoder/csrc"], optional=True)],
    cmdclass={"build_ext": BuildExt},
)
