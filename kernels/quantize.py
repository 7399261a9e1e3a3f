"""Group-wise min-max quantisation kernels: dispatch between the CUDA and the CPU path.

Both paths implement exactly the normative quantiser of ``gsz.decoder.quant`` (float32 min/max
per group, float64 step s = (M - m) / (2^q - 1) or 1, k = clamp(rint((x - m) / s), 0, 2^q - 1)),
so symbols are bit-identical whichever runs; loss tables agree to float64 rounding.

Device choice: ``device=None`` picks CUDA when torch has CUDA and a GPU is present and the
extension builds (``gsz.kernels.quantize_cuda``), else the CPU path: the torch reference
(``gsz.kernels.quantize_cpu``), its symbols, loss table and finiteness check in C where
``gsz.decoder.native`` is enabled.  ``device="cpu"`` / ``"cuda"`` force one (``"cuda"`` raises
when it is unavailable).  Outputs are always numpy arrays on the host.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from ..decoder import native
from ..decoder.errors import GszError
from ..decoder.quant import MAX_BITS, MIN_BITS
from ..decoder.threads import spans, thread_map

from . import quantize_cpu


def _as_tensor(x) -> torch.Tensor:
    """float32 contiguous CPU/CUDA tensor [C, L]; raises GszError on bad shape / non-finite data."""
    t = torch.from_numpy(np.ascontiguousarray(x)) if isinstance(x, np.ndarray) else x
    if not isinstance(t, torch.Tensor):
        raise GszError(f"quantiser input must be a torch.Tensor or numpy array, got {type(x).__name__}")
    if t.ndim != 2:
        raise GszError(f"quantiser input must be [C, L], got shape {tuple(t.shape)}")
    if not t.is_floating_point():
        raise GszError(f"quantiser input must be floating point, got {t.dtype}")
    t = t.to(torch.float32).contiguous()
    if not _all_finite(t):
        raise GszError("quantiser input contains NaN or infinity")
    return t


def _all_finite(t: torch.Tensor) -> bool:
    """Every value finite; on the CPU through the accelerator's one pass where it is built
    (torch's check makes a [C, L] bool tensor first)."""
    if t.device.type == "cpu" and native.enabled():
        return bool(native.module().all_finite(t.numpy()))
    return bool(torch.isfinite(t).all())


def _check_blocks(num_blocks) -> int:
    if not isinstance(num_blocks, (int, np.integer)) or int(num_blocks) < 1:
        raise GszError(f"num_blocks must be a positive integer, got {num_blocks!r}")
    return int(num_blocks)


def _pick_device(device) -> str:
    if device is None:
        from . import quantize_cuda
        return "cuda" if quantize_cuda.available() else "cpu"
    dev = str(torch.device(device).type)
    if dev == "cuda":
        from . import quantize_cuda
        if not quantize_cuda.available():
            raise GszError("CUDA quantiser requested but CUDA (or its extension build) is unavailable")
    elif dev != "cpu":
        raise GszError(f"unsupported quantiser device {device!r}")
    return dev


def quantize_all_bits(x, num_blocks: int, bit_range: tuple[int, int] = (MIN_BITS, MAX_BITS), *,
                      device=None) -> tuple[Callable[[np.ndarray], np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Min/max of every (channel, block) group and the loss table for all bit-widths at once.

    x: float32 tensor or array [C, L] (finite); blocks per channel: split_lengths(L, num_blocks).
    bit_range: inclusive (lo, hi) with 1 <= lo <= hi <= 16.
    Returns (symbols_fn, mins, maxs, loss):
      mins, maxs: float32 [C, B] -- the values the stream stores;
      loss: float64 [C, B, 16], loss[c, b, q-1] = sum over group (c, b) of (x - x_hat_q)^2 with
        x_hat_q the decoder's dequantised value at q bits; +inf for q outside bit_range; 0 for
        empty groups.  Non-increasing in q up to rounding for real data.
      symbols_fn(bits int [C, B]) -> int32 [C, L]: symbols for a chosen allocation, reusing these
        mins/maxs (same result as quantize_groups).
    """
    lo, hi = (int(bit_range[0]), int(bit_range[1]))
    if not (MIN_BITS <= lo <= hi <= MAX_BITS):
        raise GszError(f"bit_range must satisfy {MIN_BITS} <= lo <= hi <= {MAX_BITS}, got {bit_range}")
    t = _as_tensor(x)
    nb = _check_blocks(num_blocks)
    dev = _pick_device(device)
    if dev == "cuda":
        from . import quantize_cuda
        mins, maxs, loss = quantize_cuda.minmax_and_loss(t, nb, lo, hi)
    else:
        t = t.cpu()
        mins, maxs = _group_minmax(t, nb)
        loss = _loss_cpu(t, nb, mins, maxs, lo, hi)
    mins_np = mins.cpu().numpy()
    maxs_np = maxs.cpu().numpy()

    def symbols_fn(bits) -> np.ndarray:
        return _quantize_with(t, nb, bits, mins, maxs, dev)

    return symbols_fn, mins_np, maxs_np, loss.cpu().numpy()


def _group_minmax(t: torch.Tensor, nb: int) -> tuple[torch.Tensor, torch.Tensor]:
    """quantize_cpu.group_minmax, channel spans on every core where torch runs one thread (the
    size search): each span's groups are its own, so the values are the same."""
    cut = spans(t.shape[0])
    if len(cut) < 2 or torch.get_num_threads() > 1:
        return quantize_cpu.group_minmax(t, nb)
    parts = thread_map(lambda i: quantize_cpu.group_minmax(t[cut[i][0]:cut[i][1]], nb), len(cut))
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


def _loss_cpu(t: torch.Tensor, nb: int, mins: torch.Tensor, maxs: torch.Tensor, lo: int,
              hi: int) -> torch.Tensor:
    """quantize_cpu.loss_all_bits (the reference), in C where the accelerator is enabled: the
    same float64 steps in one pass per width (2.5x faster single-threaded; the search runs
    torch on one thread), sums agreeing to ~1e-14 relative."""
    if not native.enabled() or t.shape[1] == 0:
        return quantize_cpu.loss_all_bits(t, nb, mins, maxs, lo, hi)
    out = np.full((t.shape[0], nb, MAX_BITS), np.inf)
    out[:, :, lo - 1:hi] = 0.0
    x, mn, mx = t.numpy(), mins.numpy(), maxs.numpy()
    cut = spans(x.shape[0])

    def run(i: int) -> None:          # channels apart: each writes its own rows of out
        a, b = cut[i]
        native.module().loss_all_bits(x[a:b], nb, mn[a:b], mx[a:b], lo, hi, out[a:b])
    thread_map(run, len(cut))
    return torch.from_numpy(out)


def _check_bits(bits, shape) -> torch.Tensor:
    b = torch.as_tensor(np.asarray(bits)).to(torch.int64)
    if tuple(b.shape) != tuple(shape):
        raise GszError(f"bits must have shape {tuple(shape)}, got {tuple(b.shape)}")
    if b.numel() and (int(b.min()) < MIN_BITS or int(b.max()) > MAX_BITS):
        raise GszError(f"bits must lie in {MIN_BITS}..{MAX_BITS}")
    return b


def _quantize_with(t, nb, bits, mins, maxs, dev) -> np.ndarray:
    b = _check_bits(bits, (t.shape[0], nb))
    if dev == "cuda":
        from . import quantize_cuda
        return quantize_cuda.quantize(t, nb, b, mins, maxs).cpu().numpy()
    if native.enabled() and t.shape[1]:
        # the same symbols, bit for bit, in one pass (the torch path's 6 passes per chunk were
        # ~5 % of a search on its single torch thread)
        sym = np.empty(tuple(t.shape), np.int32)
        x, mn, mx = t.cpu().numpy(), mins.cpu().numpy(), maxs.cpu().numpy()
        bits64 = np.ascontiguousarray(b.numpy(), np.int64)
        cut = spans(x.shape[0])

        def run(i: int) -> None:      # channels apart: each writes its own rows of sym
            a, e = cut[i]
            native.module().quantize_groups(x[a:e], nb, mn[a:e], mx[a:e], bits64[a:e], sym[a:e])
        thread_map(run, len(cut))
        return sym
    return quantize_cpu.quantize(t.cpu(), nb, b, mins.cpu(), maxs.cpu()).numpy()


def quantize_groups(x, num_blocks: int, bits, *, device=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quantise every (channel, block) group of x [C, L] at its bit-width bits[c, b] (1..16).

    Returns (symbols int32 [C, L], mins float32 [C, B], maxs float32 [C, B]); dequantise with
    gsz.decoder.quant.dequantize_groups(symbols, mins, maxs, bits, split_lengths(L, B)).
    """
    t = _as_tensor(x)
    nb = _check_blocks(num_blocks)
    dev = _pick_device(device)
    if dev == "cuda":
        from . import quantize_cuda
        mins, maxs = quantize_cuda.minmax(t, nb)
    else:
        t = t.cpu()
        mins, maxs = _group_minmax(t, nb)
    sym = _quantize_with(t, nb, bits, mins, maxs, dev)
    return sym, mins.cpu().numpy(), maxs.cpu().numpy()
