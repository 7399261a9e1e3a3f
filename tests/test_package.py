"""Packaging contracts: one import name, and a decoder core that never needs torch."""
import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest


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
    import gsz.evaluation
    import gsz.kernels
    import gsz.viewer
    for m in (gsz.decoder, gsz.encoder, gsz.evaluation, gsz.kernels, gsz.viewer):
        assert m.__name__.startswith("gsz.")


def test_every_subpackage_ships():
    """Each folder with an __init__.py is in pyproject's package list (one left out would be
    missing from the wheel while an editable install still finds it)."""
    tomllib = pytest.importorskip("tomllib")
    root = Path(__file__).resolve().parent.parent
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = [d for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")
               and d.name not in ("tests", "bench", "build", "dist")]
    found = {".".join(("gsz",) + p.parent.relative_to(root).parts) for d in folders for p in d.rglob("__init__.py")}
    assert found <= listed, found - listed


def test_evaluation_never_imports_the_encoder():
    """gsz.encoder and gsz.viewer import gsz.evaluation, so no evaluation module may import them,
    not even inside a function (that would make the packages import each other in a circle)."""
    root = Path(__file__).resolve().parent.parent
    found = []
    for path in (root / "evaluation").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):    # relative: level 1 is gsz.evaluation, 2 is gsz
                base = ".".join(["gsz", "evaluation"][:3 - node.level] if node.level else [])
                base = ".".join(filter(None, [base, node.module]))
                names = [f"{base}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            found += [f"{path.name}: {n}" for n in names if n.startswith(("gsz.encoder", "gsz.viewer"))]
    assert not found
