"""Size budgets: parsing, echoing, profiles (gsz.decoder.sizes)."""
import pytest

from gsz.decoder.errors import GszError
from gsz.decoder.sizes import (PROFILES, SizeSpecError, budget_from_args, format_size, parse_ratio,
                               parse_size, size_style)


@pytest.mark.parametrize("text, expected", [
    ("5MB", 5_000_000), ("5 MB", 5_000_000), ("5mb", 5_000_000), ("5M", 5_000_000),
    ("800kB", 800_000), ("800KB", 800_000), ("800k", 800_000), ("1GB", 10 ** 9), ("1g", 10 ** 9),
    ("4.5MiB", int(4.5 * 2 ** 20)), ("4.5 mib", int(4.5 * 2 ** 20)), ("2Mi", 2 * 2 ** 20),
    ("3KiB", 3072), ("1GiB", 2 ** 30), ("123456", 123456), ("123456B", 123456), ("123456 b", 123456),
    ("0.5MB", 500_000), (".5MB", 500_000), ("2e6", 2_000_000), ("1.5e3kB", 1_500_000),
    ("4.1MB", 4_100_000), ("  7 MB  ", 7_000_000), (123456, 123456),
])
def test_parse_size_accepts_decimal_binary_and_plain_bytes(text, expected):
    assert parse_size(text) == expected


@pytest.mark.parametrize("text, needle", [
    ("5 parsecs", "unit"), ("5 Mbps", "unit"), ("-5MB", "positive"), ("0", "at least 1 byte"),
    ("0MB", "at least 1 byte"), ("0.0000001B", "at least 1 byte"), ("MB", "cannot read"),
    ("", "cannot read"), ("5..MB", "cannot read"), ("1e30GB", "implausibly large"),
    (0, "positive"), (-3, "positive"), (None, "string"), (True, "number of bytes"), ("nan MB", "cannot read"),
])
def test_parse_size_rejects_nonsense_with_a_clear_error(text, needle):
    with pytest.raises(SizeSpecError) as e:
        parse_size(text)
    assert needle in str(e.value)
    assert isinstance(e.value, GszError)


@pytest.mark.parametrize("text", ["5MB", "4.5MiB", "800kB", "123456", "2GiB", "1.25 GB", "3 KiB"])
def test_format_size_echoes_a_budget_in_the_users_unit(text):
    n = parse_size(text)
    echoed = format_size(n, size_style(text))
    assert echoed.split()[1] == size_style(text)
    assert parse_size(echoed.replace(" ", "")) == n


def test_format_size_styles():
    assert format_size(5_000_000, "MB") == "5 MB"
    assert format_size(4.5 * 2 ** 20, "MiB") == "4.5 MiB"
    assert format_size(1_234_567, "MB") == "1.235 MB"
    assert format_size(999, "auto") == "999 B"
    assert format_size(1_500_000, "auto") == "1.5 MB"
    assert format_size(3 * 2 ** 30, "auto-binary") == "3 GiB"
    assert size_style("5mb") == "MB" and size_style("5 mib") == "MiB" and size_style("100") == "B"
    with pytest.raises(SizeSpecError):
        format_size(10, "parsec")


def test_profiles_span_8_to_40x_and_get_smaller():
    ratios = [PROFILES[k] for k in ("large", "medium", "small", "very-small", "tiny")]
    assert ratios == sorted(ratios) and ratios[0] == 8 and ratios[-1] == 40
    ply = 88_906_232
    budgets = [budget_from_args(profile=k, ply_bytes=ply) for k in PROFILES]
    assert budgets == sorted(budgets, reverse=True)
    assert budget_from_args(profile="large", ply_bytes=ply) == ply // 8
    # spelling variants of the two-word profile
    assert budget_from_args(profile="Very_Small", ply_bytes=ply) == budget_from_args(profile="very small", ply_bytes=ply)


def test_budget_from_args_exactly_one_source():
    assert budget_from_args(size="5MB") == 5_000_000
    assert budget_from_args(ratio="20x", ply_bytes=1_000_000) == 50_000
    assert budget_from_args(ratio=12.5, ply_bytes=1_000_000) == 80_000
    for kw in ({}, {"size": "5MB", "ratio": 10}, {"size": "1MB", "profile": "tiny"}):
        with pytest.raises(SizeSpecError, match="exactly one"):
            budget_from_args(ply_bytes=10 ** 6, **kw)
    with pytest.raises(SizeSpecError, match="unknown profile"):
        budget_from_args(profile="huge", ply_bytes=10 ** 6)
    with pytest.raises(SizeSpecError, match="PLY size"):
        budget_from_args(ratio=10)
    with pytest.raises(SizeSpecError, match="> 1"):
        budget_from_args(ratio="0.5x", ply_bytes=10 ** 6)
    with pytest.raises(SizeSpecError, match="ratio"):
        parse_ratio("lots")
    assert parse_ratio("20X") == 20.0
