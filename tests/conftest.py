import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
SHARED = Path(os.environ.get("GSZ_SHARED", ROOT.parent / "shared")) / "data"

SAMPLE_SH0 = DATA / "houseplant_sh0_20k.ply"
SAMPLE_SH3 = DATA / "measuring_jug_sh3_12k.ply"


def shared_scene(name: str) -> Path:
    """Path of a scene in ../shared/data, or skip the test cleanly when it is absent."""
    p = SHARED / name
    if not p.exists():
        pytest.skip(f"../shared/data/{name} not present")
    return p


@pytest.fixture(scope="session")
def sample_sh0():
    import gsz
    return gsz.read_ply(SAMPLE_SH0)


@pytest.fixture(scope="session")
def sample_sh3():
    import gsz
    return gsz.read_ply(SAMPLE_SH3)


@pytest.fixture(params=["native", "numpy"])
def each_decoder_path(request):
    """Runs the test once on the C accelerator and once on the NumPy reference (name the
    fixture in ``pytest.mark.usefixtures``); skips the native run where it is not built."""
    from gsz.decoder import native
    if request.param == "native" and not native.native_available():
        pytest.skip("native accelerator not built")
    old = native.set_enabled(request.param == "native")
    yield request.param
    native.set_enabled(old)
