"""docs/results/ is generated from bench/out/*.json by bench/results.py: the committed pages must be
what it writes now (regenerate with ``.venv/bin/python bench/results.py``) and stay small."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ROOT / "docs" / "results"


def test_results_pages_are_current():
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "results.py"), "--check"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


def test_results_pages_fit_40_kb():
    pages = sorted(PAGES.glob("*.md"))
    assert pages
    assert sum(p.stat().st_size for p in pages) <= 40_000


def test_results_pages_name_their_sources():
    for p in PAGES.glob("*.md"):
        if p.name == "README.md":
            continue
        text = p.read_text()
        assert "| JSON | command | commit | machine | run |" in text, p.name
