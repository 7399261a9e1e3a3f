"""CPU (torch) implementation of the group-wise min-max quantiser and its loss table.

Contracts are those of ``gsz.kernels.quantize`` (the dispatcher validates inputs; these
functions assume a finite, contiguous float32 CPU tensor [C, L]).  The quantiser arithmetic is
the normative one of ``gsz.decoder.quant`` (float64 step from the float32 min/max, rint =
round-half-even), so symbols are bit-identical to the numpy reference and to the CUDA kernel.

Performance (platform-notes section 6): every fresh tensor of >= 32 MB costs ~30 ms of page
faults here, so the work runs over CHUNKS of whole groups (~1M elements, 8 MB float64) with
preallocated scratch buffers reused across the 16 bit-widths.
"""
from __future__ import annotations

import torch

from ..decoder.quant import MAX_BITS

# Elements per chunk: 1M float64 = 8 MB per scratch buffer (three buffers live at once).
CHUNK_ELEMENTS = 1 << 20


def _block_views(x: torch.Tensor, num_blocks: int):
    """Split x [C, L] into at most two regular 3-D views of whole blocks.

    split_lengths gives `extra` blocks of (base+1) elements followed by (B - extra) of `base`,
    so each part is a plain reshape.  Yields (first_block_index, view [C, nb, n]) for n > 0.
    """
    c, length = x.shape
    base, extra = divmod(length, num_blocks)
    head = extra * (base + 1)
    if extra:
        yield 0, x[:, :head].reshape(c, extra, base + 1)
    if base and num_blocks - extra:
        yield extra, x[:, head:].reshape(c, num_blocks - extra, base)


def group_minmax(x: torch.Tensor, num_blocks: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-(channel, block) min and max: float32 [C, B] each (0 for empty blocks)."""
    c = x.shape[0]
    mins = torch.zeros((c, num_blocks), dtype=torch.float32)
    maxs = torch.zeros((c, num_blocks), dtype=torch.float32)
    for b0, v in _block_views(x, num_blocks):
        lo, hi = torch.aminmax(v, dim=2)
        mins[:, b0:b0 + v.shape[1]] = lo
        maxs[:, b0:b0 + v.shape[1]] = hi
    return mins, maxs


def _levels(bits: torch.Tensor) -> torch.Tensor:
    return torch.pow(2.0, bits.to(torch.float64)) - 1.0


def _steps(mins: torch.Tensor, maxs: torch.Tensor, levels: torch.Tensor) -> torch.Tensor:
    """Normative step (gsz.decoder.quant.step_sizes) in torch float64."""
    span = maxs.to(torch.float64) - mins.to(torch.float64)
    return torch.where(span > 0, span / levels, torch.ones_like(span))


def _chunks(num_groups: int, group_len: int):
    per = max(1, CHUNK_ELEMENTS // max(1, group_len))
    for g0 in range(0, num_groups, per):
        yield g0, min(num_groups, g0 + per)


def loss_all_bits(x: torch.Tensor, num_blocks: int, mins: torch.Tensor, maxs: torch.Tensor,
                  bit_lo: int = 1, bit_hi: int = MAX_BITS) -> torch.Tensor:
    """Omega[c, b, q-1] = sum over the group of (x - x_hat_q)^2, float64 [C, B, 16].

    Entries for q outside [bit_lo, bit_hi] are +inf; empty groups have loss 0.  Errors are
    formed and summed in float64 (no float32 cancellation at high bit-widths).
    """
    c = x.shape[0]
    loss = torch.full((c, num_blocks, MAX_BITS), float("inf"), dtype=torch.float64)
    loss[:, :, bit_lo - 1:bit_hi] = 0.0
    for b0, v in _block_views(x, num_blocks):
        nb, n = v.shape[1], v.shape[2]
        for ci in range(c):
            lo = mins[ci, b0:b0 + nb].reshape(-1, 1).to(torch.float64)
            span = maxs[ci, b0:b0 + nb].reshape(-1, 1).to(torch.float64) - lo
            for g0, g1 in _chunks(nb, n):
                d = v[ci, g0:g1].to(torch.float64)
                d -= lo[g0:g1]                     # exact: difference of two float32 in float64
                k = torch.empty_like(d)
                e = torch.empty_like(d)
                sp = span[g0:g1]
                for q in range(bit_lo, bit_hi + 1):
                    levels = float((1 << q) - 1)
                    s = torch.where(sp > 0, sp / levels, torch.ones_like(sp))
                    torch.div(d, s, out=k)
                    torch.round(k, out=k)          # round half to even, like numpy.rint / CUDA rint
                    k.clamp_(0.0, levels)
                    torch.mul(k, s, out=e)
                    torch.sub(d, e, out=e)
                    loss[ci, b0 + g0:b0 + g1, q - 1] = torch.linalg.vecdot(e, e)
    return loss


def quantize(x: torch.Tensor, num_blocks: int, bits: torch.Tensor, mins: torch.Tensor,
             maxs: torch.Tensor) -> torch.Tensor:
    """Symbols k = clamp(rint((x - m) / s), 0, 2^q - 1) as int32 [C, L] (normative formula)."""
    c, length = x.shape
    sym = torch.zeros((c, length), dtype=torch.int32)
    levels_all = _levels(bits)
    steps_all = _steps(mins, maxs, levels_all)
    base, extra = divmod(length, num_blocks)
    for b0, v in _block_views(x, num_blocks):
        nb, n = v.shape[1], v.shape[2]
        start = b0 * (base + 1) if b0 == 0 else extra * (base + 1)
        for ci in range(c):
            out = sym[ci, start:start + nb * n].view(nb, n)   # contiguous row slice: a true view
            lo = mins[ci, b0:b0 + nb].reshape(-1, 1).to(torch.float64)
            s = steps_all[ci, b0:b0 + nb].reshape(-1, 1)
            lv = levels_all[ci, b0:b0 + nb].reshape(-1, 1)
            for g0, g1 in _chunks(nb, n):
                d = v[ci, g0:g1].to(torch.float64)
                d -= lo[g0:g1]
                d /= s[g0:g1]
                torch.round(d, out=d)
                d.clamp_(min=0.0)
                torch.minimum(d, lv[g0:g1], out=d)
                out[g0:g1] = d.to(torch.int32)
    return sym
