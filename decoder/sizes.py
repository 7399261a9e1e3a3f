"""Size budgets: parsing "5MB" / "4.5MiB" / "123456", echoing them back, and named profiles.

A budget is always an integer number of BYTES of the whole .gsz file.  Pure Python, in the core
because the encoder's and the viewer's command lines both read budgets.

Units (case-insensitive where unambiguous):
    B, (none)                     bytes
    kB KB k K, MB M, GB G, TB T   decimal: 10^3, 10^6, 10^9, 10^12 bytes (SI, as disks and most
                                  tools count; "MB" means 10^6 bytes here -- say MiB for 2^20)
    KiB Ki, MiB Mi, GiB Gi, TiB   binary: 2^10, 2^20, 2^30, 2^40 bytes
Lower-case "mb"/"mib" are accepted too (nobody means millibytes); "b" alone is bytes (a bit
budget is never what a user means by a file size).  Decimals are allowed ("4.5MiB"); the
result is rounded down to whole bytes.

Profiles (MesonGS++ names its five operating points Large / Medium / Small / Very Small / Tiny
but fixes no numbers; the reference code uses FCGS's per-scene sizes).  gsz defines them as
compression ratios against the input PLY, a geometric ladder (x1.5 per step) spanning the
8x..40x range where the paper reports its results (its headline is "over 34x"):

    large 8x, medium 12x, small 18x, very-small 27x, tiny 40x
"""
from __future__ import annotations

import math
import re
from fractions import Fraction

from .errors import GszUsageError


class SizeSpecError(GszUsageError):
    """A size, ratio or profile given by the user cannot be understood."""


# unit (lower case) -> (bytes per unit, canonical spelling)
_UNITS = {
    "": (1, "B"), "b": (1, "B"), "byte": (1, "B"), "bytes": (1, "B"),
    "k": (10 ** 3, "kB"), "kb": (10 ** 3, "kB"),
    "m": (10 ** 6, "MB"), "mb": (10 ** 6, "MB"),
    "g": (10 ** 9, "GB"), "gb": (10 ** 9, "GB"),
    "t": (10 ** 12, "TB"), "tb": (10 ** 12, "TB"),
    "ki": (2 ** 10, "KiB"), "kib": (2 ** 10, "KiB"),
    "mi": (2 ** 20, "MiB"), "mib": (2 ** 20, "MiB"),
    "gi": (2 ** 30, "GiB"), "gib": (2 ** 30, "GiB"),
    "ti": (2 ** 40, "TiB"), "tib": (2 ** 40, "TiB"),
}
_STYLE_FACTORS = {canon: f for f, canon in _UNITS.values()}

_SIZE_RE = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE]([+-]?[0-9]+))?\s*([A-Za-z]*)\s*$")

# compression ratio vs the input PLY (input bytes / output bytes)
PROFILES = {"large": 8.0, "medium": 12.0, "small": 18.0, "very-small": 27.0, "tiny": 40.0}

MAX_BUDGET = 2 ** 50        # 1 PiB: anything larger is a typo, not a budget


def parse_size(text) -> int:
    """Bytes (int >= 1) of a size written like "5MB", "4.5 MiB", "123456", "123456B", "2e6".

    Raises SizeSpecError naming the problem for unknown units, negative/zero/non-numeric or
    absurdly large sizes.  ints are accepted as bytes.
    """
    if isinstance(text, bool):
        raise SizeSpecError(f"size must be a number of bytes or a string like '5MB', got {text!r}")
    if isinstance(text, int):
        n = int(text)
        if n <= 0:
            raise SizeSpecError(f"size must be positive, got {n} bytes")
        if n > MAX_BUDGET:
            raise SizeSpecError(f"size {n} bytes is implausibly large (max 1 PiB)")
        return n
    if not isinstance(text, str):
        raise SizeSpecError(f"size must be a string like '5MB' or an int, got {type(text).__name__}")
    s = text.strip()
    if s.startswith("-"):
        raise SizeSpecError(f"size must be positive, got {text!r}")
    m = _SIZE_RE.match(s)
    if not m:
        raise SizeSpecError(f"cannot read size {text!r}: expected a number and an optional unit "
                            f"such as 5MB, 4.5MiB, 800kB or 123456")
    num, exp, unit = m.groups()
    key = unit.lower()
    if key not in _UNITS:
        raise SizeSpecError(f"unknown size unit {unit!r} in {text!r}: use B, kB, MB, GB (powers of "
                            f"1000) or KiB, MiB, GiB (powers of 1024)")
    if exp and abs(int(exp)) > 30:
        raise SizeSpecError(f"size {text!r} is implausibly large (max 1 PiB)" if int(exp) > 0
                            else f"size must be at least 1 byte, got {text!r}")
    # exact decimal arithmetic: "4.1MB" is 4100000 bytes, not 4099999.999...
    n_bytes = Fraction(num) * Fraction(10) ** int(exp or 0) * _UNITS[key][0]
    if n_bytes > MAX_BUDGET:
        raise SizeSpecError(f"size {text!r} is implausibly large (max 1 PiB)")
    n = math.floor(n_bytes)
    if n <= 0:
        raise SizeSpecError(f"size must be at least 1 byte, got {text!r}")
    return n


def size_style(text) -> str:
    """Canonical unit of a size string ("5mb" -> "MB", "3 MiB" -> "MiB", "1200" -> "B")."""
    if isinstance(text, int):
        return "B"
    m = _SIZE_RE.match(str(text).strip())
    if not m or m.group(3).lower() not in _UNITS:
        raise SizeSpecError(f"cannot read size {text!r}")
    return _UNITS[m.group(3).lower()][1]


def format_size(n_bytes: int | float, style: str = "auto") -> str:
    """Human-readable size.

    style: a canonical unit ("B", "kB", "MB", "GB", "TB", "KiB", "MiB", "GiB", "TiB") to echo a
    budget in the unit the user wrote (see :func:`size_style`), "auto" (decimal, the largest unit
    that keeps the number >= 1) or "auto-binary".  Bytes print exactly; other units with 3
    significant decimals (e.g. "4.5 MiB", "5 MB", "1.234 MB").
    """
    n = float(n_bytes)
    if style in ("auto", "auto-binary"):
        ladder = ["B", "kB", "MB", "GB", "TB"] if style == "auto" else ["B", "KiB", "MiB", "GiB", "TiB"]
        style = "B"
        for u in ladder:
            if abs(n) >= _STYLE_FACTORS[u]:
                style = u
    if style not in _STYLE_FACTORS:
        raise SizeSpecError(f"unknown size style {style!r}; one of {sorted(_STYLE_FACTORS)} or 'auto'")
    if style == "B":
        return f"{int(round(n))} B"
    v = n / _STYLE_FACTORS[style]
    txt = f"{v:.3f}".rstrip("0").rstrip(".")
    return f"{txt} {style}"


def parse_ratio(text) -> float:
    """Compression ratio (> 1) from "20", "20x", "20X", 20.0; SizeSpecError otherwise."""
    s = str(text).strip().lower()
    if s.endswith("x"):
        s = s[:-1].strip()
    try:
        r = float(s)
    except ValueError:
        raise SizeSpecError(f"cannot read compression ratio {text!r}: expected e.g. 20 or 20x") from None
    if not math.isfinite(r) or r <= 1.0:
        raise SizeSpecError(f"compression ratio must be a number > 1, got {text!r}")
    return r


def budget_from_args(size=None, ratio=None, profile=None, *, ply_bytes: int | None = None) -> int:
    """Budget in bytes from exactly one of: ``size`` (parse_size), ``ratio`` (input PLY bytes /
    ratio) or ``profile`` (a PROFILES name; its ratio).  ``ply_bytes`` (the input PLY's size)
    is required for ratio and profile.  Raises SizeSpecError on none/several/bad values."""
    given = [k for k, v in (("size", size), ("ratio", ratio), ("profile", profile)) if v is not None]
    if len(given) != 1:
        raise SizeSpecError("give exactly one of a size (e.g. 5MB), a compression ratio (e.g. 20x) "
                            f"or a profile ({', '.join(PROFILES)}); got "
                            f"{', '.join(given) if given else 'none'}")
    if size is not None:
        return parse_size(size)
    if profile is not None:
        key = str(profile).strip().lower().replace("_", "-").replace(" ", "-")
        if key not in PROFILES:
            raise SizeSpecError(f"unknown profile {profile!r}; choose one of "
                                f"{', '.join(f'{k} ({v:g}x)' for k, v in PROFILES.items())}")
        r = PROFILES[key]
    else:
        r = parse_ratio(ratio)
    if ply_bytes is None or int(ply_bytes) <= 0:
        raise SizeSpecError("a ratio or profile needs the input PLY size (ply_bytes > 0)")
    n = int(math.floor(int(ply_bytes) / r))
    if n < 1:
        raise SizeSpecError(f"ratio {r:g} of a {ply_bytes}-byte input leaves less than one byte")
    return n
