"""Packaging contracts: one import name, and a decoder core that never needs torch."""
import subprocess
import sys
import textwrap


def test_decoder_imports_without_torch():
    code = textwrap.dedent("""
        import sys, builtins
        real_import = builtins.__import__
        def guard(name, *a, **k):
            if name == 'torch' or name.startswith('torch.') or name == 'scipy' or name.startswith('scipy.'):
                raise ImportError('blocked for this test: ' + name)
            return real_import(name, *a, **k)
        builtins.__import__ = guard
        import gsz, gsz.decoder
        from gsz.decoder import read_ply, GaussianCloud
        import gsz.decoder.container, gsz.decoder.bytesio
        import pkgutil, importlib
        for m in pkgutil.iter_modules(gsz.decoder.__path__):
            if m.name != 'cli':
                importlib.import_module('gsz.decoder.' + m.name)
        assert 'torch' not in sys.modules
        print('ok')
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_subpackages_live_in_gsz_namespace():
    import gsz.decoder
    import gsz.encoder
    import gsz.kernels
    import gsz.viewer
    for m in (gsz.decoder, gsz.encoder, gsz.kernels, gsz.viewer):
        assert m.__name__.startswith("gsz.")
