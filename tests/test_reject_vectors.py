"""format_spec/vectors/reject: every must-reject vector is rejected, on both decoder paths and by
the streaming reader, with the error its manifest names (issue 19; GSZ.md §12)."""
import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

import gsz.decoder.errors as errors
from gsz.decoder import StreamDecoder, decode

REJECT = Path(__file__).resolve().parent.parent / "format_spec" / "vectors" / "reject"
MANIFEST = json.loads((REJECT / "manifest.json").read_text())


def _generator():
    spec = importlib.util.spec_from_file_location("reject_generate", REJECT / "generate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_vectors_are_what_their_generator_writes():
    gen = _generator()
    made = gen.vectors()
    assert sorted(p.name for p in REJECT.glob("*.gsz")) == sorted(name for name, *_ in made)
    assert [row["file"] for row in MANIFEST] == [name for name, *_ in made]
    for (name, data, rule, error, message, args), row in zip(made, MANIFEST):
        assert (REJECT / name).read_bytes() == data, name
        assert (row["rule"], row["error"], row["message"], row.get("decode", {})) == (rule, error, message, args)
    assert len(made) >= 90 and len({name for name, *_ in made}) == len(made)


@pytest.mark.usefixtures("each_decoder_path")
@pytest.mark.parametrize("layers", [1, 2])
def test_the_base_the_vectors_mutate_is_valid(layers):
    # each vector breaks one rule of a file that decodes: the base itself must decode
    from gsz.decoder.container import write_container  # noqa: F401  (the base is written by hand)
    gen = _generator()
    cloud = decode(gen.join(*gen.base_chunks(layers)))
    assert len(cloud) == 135 * layers and cloud.sh_degree == 1
    assert np.all(cloud.opacities == 0) and np.all(cloud.sh_rest == 0) and np.all(cloud.scales == 0)


@pytest.mark.usefixtures("each_decoder_path")
def test_the_rwgt_base_is_valid():
    # the RWGT vectors break one rule each of a valid RWGT chunk (and of SHCL's RWGT form)
    gen = _generator()
    base = gen.join(*gen.base_chunks())
    ok = gen.rwgt(2, [1, 3], gen.single_stream(body=gen.model_body([1], lo=[1])))
    plain, weighted = decode(base), decode(gen.with_rwgt(base, ok))
    assert len(weighted) == 135 and np.array_equal(weighted.positions, plain.positions)
    both = decode(gen.with_shcl(gen.with_rwgt(base, ok), 135, b"\x00"))
    assert len(both) == 135


@pytest.mark.usefixtures("each_decoder_path")
@pytest.mark.parametrize("row", MANIFEST, ids=lambda r: r["file"][:-4])
def test_vector_is_rejected_with_its_documented_error(row):
    path = REJECT / row["file"]
    cls = getattr(errors, row["error"])
    with pytest.raises(cls, match=re.escape(row["message"])) as e:
        decode(path, **row.get("decode", {}))
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg and isinstance(e.value, errors.GszFormatError)


@pytest.mark.usefixtures("each_decoder_path")
@pytest.mark.parametrize("row", [r for r in MANIFEST if r["error"] != "GszTruncatedError"],
                         ids=lambda r: r["file"][:-4])
def test_vector_is_rejected_by_the_streaming_reader(row):
    # a streaming reader sees the same faults (a truncated file is its documented non-error)
    args = row.get("decode", {})
    dec = StreamDecoder(max_gaussians=args.get("max_gaussians"), max_layers=args.get("layers"), source="s.gsz")
    data = (REJECT / row["file"]).read_bytes()
    with pytest.raises(getattr(errors, row["error"]), match=re.escape(row["message"])):
        for start in range(0, len(data), 4096):
            dec.feed(data[start:start + 4096])
        dec.finish()


@pytest.mark.usefixtures("each_decoder_path")
def test_non_minimal_varints_are_accepted():
    # ENTROPY.md §1: a decoder must accept any form of up to 9 bytes (the vectors' base with its
    # scale stream's varints padded: 0x81 0x80 0x00 is 1)
    gen = _generator()
    base = gen.join(*gen.base_chunks())

    def wide(v: int, extra: int) -> bytes:
        b = bytearray(gen.varint(v))
        b[-1] |= 0x80
        return bytes(b) + b"\x80" * (extra - 1) + b"\x00"

    body = wide(3, 2) + wide(1, 8) * 3 + wide(0, 1) * 3
    assert len(wide(1, 8)) == 9
    stream = wide(len(body) << 1, 3) + body + wide(1, 4) + wide(0, 2) + (1 << 16).to_bytes(4, "little")
    padded = gen.with_direct_set(base, stream)
    assert len(padded) > len(base) + 30
    assert decode(padded).equals(decode(base))
    too_long = gen.with_direct_set(base, wide(len(body) << 1, 9) + body + wide(1, 4) + wide(0, 2)
                                   + (1 << 16).to_bytes(4, "little"))
    with pytest.raises(errors.GszFormatError, match="varint too long"):
        decode(too_long)
