"""EncodeReport.to_json() prints what gsz-encode --json printed when the report was a plain dict:
the same keys in the same order for a fixed configuration and for the size search, with and
without a .glb wrapper, --report, input fixes and a shortfall note."""
import json

import numpy as np
import pytest

import gsz
from codec_util import sample
from gsz.encoder.encode_report import (MODE_FIXED, MODE_SEARCH, EncodeReport, FixedDetails, SearchDetails,
                                       WrittenFile)

# the keys gsz-encode --json printed before the typed report (captured on tests/data samples),
# and keys added since at the place given: the search's "sh_colour" (format 1.6) after "sh_path",
# the fixed configuration's after "sh_degree" (format 1.7: an SH-0 file's DC has a colour space)
FIXED = ["bytes", "input_gaussians", "kept_after_prune", "voxels", "bytes_per_gaussian", "depth",
         "merged_fraction", "sh_degree", "sh_colour", "components", "sh", "seconds", "total_seconds", "memory", "options",
         "layers"]
SEARCH = ["mode", "target_bytes", "bytes", "deviation", "reserve", "depth", "input_gaussians", "voxels",
          "bytes_per_gaussian", "sh_degree", "codebook_size", "sh_keep", "sh_path", "sh_colour", "layers",
          "layer_blocks",
          "bits", "calibration", "calibration_all", "first_layer", "candidates", "screened", "dropped",
          "train_psnr", "channel_weights", "beta", "eval_views", "eval_size", "components", "seconds",
          "total_seconds", "memory", "cpu_seconds"]
WRITTEN = ["gsz_bytes", "input", "output", "input_bytes", "ratio"]
WRITTEN_GLB = ["gsz_bytes", "container", "input", "output", "input_bytes", "ratio"]

CLI_BEFORE = {   # case -> the printed keys
    "fixed": FIXED + WRITTEN,
    "fixed .glb": FIXED + WRITTEN_GLB,
    "fixed --report": FIXED + WRITTEN + ["bits", "report_files"],
    "search --report": SEARCH + WRITTEN + ["target", "report_files"],
    "search .glb": SEARCH + WRITTEN_GLB + ["target", "gsz_target_bytes"],
}


def _report(mode, **kw) -> EncodeReport:
    shared = dict(bytes=1000, input_gaussians=50, voxels=40, bytes_per_gaussian=25.0, depth=9, sh_degree=0,
                  reserve=0.8, codebook_size=0, sh_keep=0, components={"geometry": 1}, layers=[],
                  seconds={"prune": 0.1}, total_seconds=1.0, memory={}, cpu_seconds=2.0)
    if mode == MODE_FIXED:
        shared["fixed"] = FixedDetails(kept_after_prune=45, merged_fraction=0.1, options={"reserve": 0.8})
    else:
        shared.update(target_bytes=1010, bits={"raht": []}, search=SearchDetails(
            deviation=-0.01, sh_path=None, layer_blocks=[80], calibration=[], calibration_all=[],
            first_layer=0.1, candidates=[], screened=[], dropped=[], train_psnr=30.0, channel_weights={},
            beta=0.1, eval_views=[], eval_size=None))
    return EncodeReport(mode=mode, **{**shared, **kw})


def _written(**kw) -> WrittenFile:
    return WrittenFile(**{**dict(input="in.ply", output="out.gsz", input_bytes=9999, ratio=9.9, gsz_bytes=1000), **kw})


@pytest.mark.parametrize("case", list(CLI_BEFORE))
def test_to_json_keys_are_the_ones_printed_before(case):
    glb = case.endswith(".glb")
    if case.startswith("fixed"):
        r = _report(MODE_FIXED)
        written = _written(container="glb" if glb else None)
    else:
        r = _report(MODE_SEARCH)
        written = _written(container="glb" if glb else None, target="1.01 kB",
                           gsz_target_bytes=900 if glb else None)
    r.written = written
    if "--report" in case:
        if r.bits is None:
            r.bits = {"raht": []}        # what write_report reads back from a fixed encode's file
        written.report_files = ["bits.png", "report.json"]
    assert list(r.to_json()) == CLI_BEFORE[case]


def test_fixes_and_note_follow_their_mode_keys_and_precede_the_written_file():
    r = _report(MODE_FIXED, input_fixes=[{"prop": "opacity"}])
    assert list(r.to_json()) == FIXED + ["input_fixes"]
    r.written = _written()
    assert list(r.to_json()) == FIXED + ["input_fixes"] + WRITTEN
    s = _report(MODE_SEARCH, input_fixes=[{"prop": "opacity"}])
    s.search.note = "file is 5.00 % below the target: ..."
    assert list(s.to_json()) == SEARCH + ["note", "input_fixes"]


def test_fixed_json_keeps_its_sh_counts_and_values_as_held():
    r = _report(MODE_FIXED, sh_degree=3, codebook_size=16, sh_keep=96)
    js = r.to_json()
    assert js["sh"] == {"kept": 96, "codebook_size": 16}
    assert _report(MODE_FIXED).to_json()["sh"] == {}           # no SH: an empty dict, as before
    assert js["options"] is r.fixed.options and js["layers"] is r.layers


def test_a_report_needs_its_own_mode_details():
    with pytest.raises(ValueError):
        _report(MODE_FIXED, search=_report(MODE_SEARCH).search)
    with pytest.raises(ValueError):
        EncodeReport(**{**_report(MODE_SEARCH).__dict__, "mode": MODE_FIXED})


FAST_CLI = ["--train-views", "1", "--importance-width", "32", "-q"]


@pytest.fixture(scope="module")
def small_ply(tmp_path_factory):
    path = tmp_path_factory.mktemp("rep") / "jug3k.ply"
    gsz.write_ply(sample("sh3", 3000), path)
    return path


@pytest.mark.parametrize("case,args", [
    ("fixed --report", ["--bits", "8", "--codebook", "16"]),
    ("search .glb", ["--ratio", "10"]),
])
def test_cli_prints_the_keys_it_printed_before(case, args, small_ply, tmp_path, capsys):
    from gsz.encoder.cli import main
    out = tmp_path / ("o.glb" if case.endswith(".glb") else "o.gsz")
    extra = ["--report", str(tmp_path / "rep")] if "--report" in case else []
    assert main([str(small_ply), "-o", str(out), *args, *FAST_CLI, "--json", *extra]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert list(printed) == CLI_BEFORE[case]
    assert printed["bytes"] == out.stat().st_size
    if extra:      # report.json: the same report, written before the chart's paths were known
        saved = json.loads((tmp_path / "rep" / "report.json").read_text())
        assert saved == {k: v for k, v in printed.items() if k != "report_files"}
    else:
        assert printed["gsz_bytes"] < printed["bytes"] and printed["gsz_target_bytes"] < printed["target_bytes"]
        assert np.isclose(printed["deviation"], (printed["gsz_bytes"] - printed["gsz_target_bytes"])
                          / printed["gsz_target_bytes"])
