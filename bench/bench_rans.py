"""Benchmark of the interleaved rANS coder (decoder/rans.py, encoder/rans.py).

    .venv/bin/python bench/bench_rans.py [--n 10000000] [--models 100] [--repeat 3]
    .venv/bin/python bench/bench_rans.py --scene ../shared/data/flowers_daffodils_sh2.ply --bits 8
    .venv/bin/python bench/bench_rans.py --channel-sets [--repeat 3]
    .venv/bin/python bench/bench_rans.py --block-loop [--repeat 5]

Data: N symbols in -128..127, M equal blocks, each a rounded Laplace with its own scale
(U(0.5, 20)), as in platform-notes.md section 5.  Reports encode/decode Msym/s (best of
--repeat, wall clock and process CPU time), payload and tables versus the per-model empirical
entropy, incremental decoding in batches of 4096, and constriction's AnsCoder with the same
quantised probabilities as a yardstick.  With --scene: opacity, scales, rotation and DC of a
real PLY, min-max quantised per channel to --bits, 80 blocks per channel (one model each).

With --channel-sets: ``gsz.encoder.groups.write_channel_set`` (quantise + both rANS model layouts
+ serialise: what every ``attribute_chunk`` of the size search runs) on the real channel sets of
houseplant and flowers (``prepare_stage(cloud, ones, 0.8)``, layer 0: RAHT AC [7, L] and scales
[3, L], 80 blocks) at uniform 8 and 12 bits and random [C, 80] bit-widths in 4..14 (seed 1).
Reports best-of---repeat wall and process-CPU time of the whole call, of its quantisation part
alone (``quantize_groups`` + ``dequantize_groups``, torch with one thread), the difference
(entropy coding), the output size and a hash of the bytes (to compare implementations: the output is normative).

With --block-loop: the native decoder's channel-set loop (``RansDecoder.decode_blocks``, uint16
symbols, as for a kept SH set) on 45 channels x 200 k symbols in 8 blocks, one model per
(channel, block), 4096 lanes, three times: 8-bit symbols (rounded Laplace around 128, scale 12),
4-bit and 2-bit ones (around 7.5, scale 2, and around 1.5, scale 0.7, clipped to 0..2^q - 1: a
refined file's kept set: the AVX2 loop decodes models of up to 8 values without gathers); the precisions
fit_model_set picks; ns a symbol of the scalar loop and of the AVX2 loop (``_native.rans_simd``),
best of --repeat.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from gsz.decoder.quant import split_lengths
from gsz.decoder.rans import RansDecoder, read_model_set, read_varint
from gsz.encoder.rans import encode_symbols, fit_model_set, write_model_set


def timed(fn, repeat):
    best_wall, best_cpu, out = np.inf, np.inf, None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        best_wall = min(best_wall, time.perf_counter() - w)
        best_cpu = min(best_cpu, time.process_time() - c)
    return out, best_wall, best_cpu


def scene_symbols(path: str, bits: int, blocks: int = 80):
    """(symbols, model ids, num models): 11 attribute channels of a PLY, per-channel min-max
    quantised to ``bits``, channel-major, one model per (channel, block of N/blocks points)."""
    from gsz.decoder.ply import read_ply
    c = read_ply(path)
    x = np.concatenate([c.opacities[:, None], c.scales, c.rotations, c.sh_dc], 1).astype(np.float64)
    n, ch = x.shape
    lo, hi = x.min(0), x.max(0)
    q = np.round((x - lo) / np.maximum(hi - lo, 1e-12) * (2 ** bits - 1)).astype(np.int64)
    block = np.arange(n) * blocks // n
    mids = (np.arange(ch)[None, :] * blocks + block[:, None]).T.ravel()
    return q.T.ravel(), mids, ch * blocks


def channel_set_bench(repeat: int, scenes=("houseplant_sh0", "flowers_daffodils_sh2")):
    import hashlib
    from pathlib import Path

    from gsz.decoder.groups import blocks_for
    from gsz.decoder.ply import read_ply
    from gsz.decoder.quant import dequantize_groups, split_lengths
    from gsz.encoder.groups import write_channel_set
    from gsz.encoder.pipeline import prepare_stage
    from gsz.kernels.quantize import quantize_groups

    import torch
    torch.set_num_threads(1)    # the quantiser's torch threads only add noise on a loaded machine
    data = Path(__file__).resolve().parents[2] / "shared" / "data"
    print(f"{'scene':12s} {'set':6s} {'bits':5s} {'total s':>8s} {'quant s':>8s} {'coding s':>8s} "
          f"{'total cpu':>9s} {'quant cpu':>9s} {'coding cpu':>10s} {'bytes':>10s} mode  sha256")
    for name in scenes:
        cloud = read_ply(str(data / f"{name}.ply"))
        layer = prepare_stage(cloud, np.ones(len(cloud)), 0.8).layers[0]
        for set_name, x in (("ac", layer.raht_ac), ("scales", layer.scales)):
            c, length = x.shape
            for bits in (8, 12, "rand"):
                b = np.random.default_rng(1).integers(4, 15, (c, 80)) if bits == "rand" else bits
                (out, _), t_all, c_all = timed(lambda: write_channel_set(x, b, 80), repeat)
                nb = blocks_for(length, 80)
                ba = np.broadcast_to(np.asarray(b, np.int64), (c, nb)).copy()

                def quant_only():
                    sym, mins, maxs = quantize_groups(x, nb, ba)
                    return dequantize_groups(sym, mins, maxs, ba, split_lengths(length, nb))

                _, t_q, c_q = timed(quant_only, repeat)
                print(f"{name[:12]:12s} {set_name:6s} {str(bits):5s} {t_all:8.3f} {t_q:8.3f} "
                      f"{t_all - t_q:8.3f} {c_all:9.3f} {c_q:9.3f} {c_all - c_q:10.3f} "
                      f"{len(out):10,d} {out[7]:4d}  "
                      f"{hashlib.sha256(out).hexdigest()[:16]}", flush=True)


def block_loop_bench(repeat: int, C: int = 45, L: int = 200_000, B: int = 8) -> None:
    for bits, centre, scale in ((8, 128, 12), (4, 7.5, 2.0), (2, 1.5, 0.7)):
        block_loop_case(repeat, bits, centre, scale, C, L, B)


def block_loop_case(repeat: int, bits: int, centre: float, scale: float, C: int, L: int, B: int) -> None:
    from gsz.decoder import native
    if not native.native_available():
        print("the native decoder is not built: nothing to time")
        return
    mod = native.module()
    rng = np.random.default_rng(0)
    m = C * B
    tab = np.arange(m, dtype=np.int64)
    block = np.repeat(np.arange(B), split_lengths(L, B))     # the codec's blocks of a channel
    mids = tab[(np.arange(C)[:, None] * B + block[None, :]).ravel()]
    top = (1 << bits) - 1
    sym = np.clip(np.round(rng.laplace(centre, scale, mids.size)), 0, top).astype(np.int64)
    models = fit_model_set(sym, mids, m)
    payload = encode_symbols(sym, mids, models, lanes=4096)
    qmax = np.full(m, top, np.int64)
    out = np.zeros(C * L, np.uint16)                 # touched once: the loops, not page faults
    print(f"{bits}-bit symbols: {C} channels x {L:,} symbols, {B} blocks, precisions "
          f"{sorted(set(models.prec.tolist()))}, 4096 lanes")
    for simd in (False, True):
        old = mod.rans_simd(simd)
        try:
            if simd and not mod.rans_simd():
                print("AVX2 loop: not available on this CPU or build")
                continue

            def run():
                dec = RansDecoder(payload, sym.size, models, use_native=True)
                dec.decode_blocks(tab, C, L, B, out, qmax=qmax)
                dec.finish()
            _, t, c = timed(run, repeat)
            assert np.array_equal(out, sym)
            print(f"{'AVX2' if simd else 'scalar':6s} loop  {t * 1e3:7.1f} ms  "
                  f"{t / sym.size * 1e9:5.2f} ns/symbol wall ({c / sym.size * 1e9:.2f} CPU)")
        finally:
            mod.rans_simd(old)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000_000)
    ap.add_argument("--models", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scene", default=None, help="real PLY instead of synthetic data")
    ap.add_argument("--bits", type=int, default=8, help="quantisation bits with --scene")
    ap.add_argument("--channel-sets", action="store_true",
                    help="time write_channel_set on real channel sets instead")
    ap.add_argument("--block-loop", action="store_true",
                    help="time the native channel-set loop, scalar against AVX2, instead")
    args = ap.parse_args(argv)
    if args.block_loop:
        block_loop_bench(args.repeat)
        return
    if args.channel_sets:
        channel_set_bench(args.repeat)
        return
    if args.scene:
        sym, mids, m = scene_symbols(args.scene, args.bits)
        n = sym.size
    else:
        n, m = args.n, args.models
        rng = np.random.default_rng(args.seed)
        mids = np.repeat(np.arange(m), -(-n // m))[:n]
        scales = rng.uniform(0.5, 20.0, m)
        sym = np.clip(np.round(rng.laplace(0.0, scales[mids])), -128, 127).astype(np.int64)

    off = sym - sym.min()
    width = int(off.max()) + 1
    key = mids.astype(np.int64) * width + off
    cnt = np.bincount(key, minlength=width * m).reshape(m, width).astype(np.float64)
    tot = cnt.sum(1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        h_bits = float(-(cnt * np.where(cnt > 0, np.log2(cnt / tot), 0)).sum())
    h_bytes = h_bits / 8

    models, t_fit, c_fit = timed(lambda: fit_model_set(sym, mids, m), 1)
    table = write_model_set(models)
    payload, t_enc, c_enc = timed(lambda: encode_symbols(sym, mids, models), args.repeat)

    def decode_all():
        ms, _ = read_model_set(table)
        dec = RansDecoder(payload, n, ms)
        out = dec.decode(mids)
        dec.finish()
        return out

    out, t_dec, c_dec = timed(decode_all, args.repeat)
    assert np.array_equal(out, sym), "round trip failed"

    nb = min(n, 2_000_000)
    sub_models = fit_model_set(sym[:nb], mids[:nb], m)
    sub_payload = encode_symbols(sym[:nb], mids[:nb], sub_models)

    def decode_batches_sub(batch=4096):
        dec = RansDecoder(sub_payload, nb, sub_models)
        parts = [dec.decode(mids[i:min(i + batch, nb)]) for i in range(0, nb, batch)]
        dec.finish()
        return np.concatenate(parts)

    outb, t_bat, c_bat = timed(decode_batches_sub, 1)
    assert np.array_equal(outb, sym[:nb])

    lanes, _ = read_varint(np.frombuffer(payload, np.uint8), 0, "lanes")

    ref = None
    try:
        import constriction
        t = models.build()
        coder = constriction.stream.stack.AnsCoder()
        for k in range(m - 1, -1, -1):
            s = sym[mids == k]
            a, c = t["sym_start"][k], t["sym_count"][k]
            idx = np.searchsorted(t["value"][a:a + c], s).astype(np.int32)
            p = t["freq"][a:a + c] / float(1 << int(models.prec[k]))
            coder.encode_reverse(idx, constriction.stream.model.Categorical(p, perfect=False))
        ref = 4 * coder.get_compressed().size
    except ImportError:
        pass

    types = np.bincount(models.types, minlength=4)
    print(f"N={n:,} symbols, M={m} models, lanes={lanes}, model types "
          f"empty/single/coarse/laplace={types.tolist()}")
    print(f"empirical entropy      {h_bytes:12,.0f} B  ({h_bits / n:.4f} bit/sym)")
    print(f"payload                {len(payload):12,} B  "
          f"({100 * (len(payload) / h_bytes - 1):+.3f} %)")
    print(f"tables                 {len(table):12,} B  "
          f"({100 * len(table) / h_bytes:.3f} % of entropy)")
    print(f"payload + tables       {len(payload) + len(table):12,} B  "
          f"({100 * ((len(payload) + len(table)) / h_bytes - 1):+.3f} %)")
    if ref is not None:
        print(f"constriction AnsCoder  {ref:12,} B  (same quantised probabilities; ours "
              f"{100 * (len(payload) / ref - 1):+.3f} %)")
    print(f"fit models             {t_fit:8.2f} s")
    print(f"encode                 {t_enc:8.3f} s  {n / t_enc / 1e6:6.1f} Msym/s wall "
          f"({n / c_enc / 1e6:.1f} Msym/s CPU)")
    print(f"decode (one call)      {t_dec:8.3f} s  {n / t_dec / 1e6:6.1f} Msym/s wall "
          f"({n / c_dec / 1e6:.1f} Msym/s CPU)")
    print(f"decode (batches 4096)  {t_bat:8.3f} s  {nb / t_bat / 1e6:6.1f} Msym/s wall on "
          f"{nb:,} symbols ({nb / c_bat / 1e6:.1f} Msym/s CPU)")


if __name__ == "__main__":
    main()
