"""The CUDA quantiser source: compiles with nvcc, and its kernel bodies match the CPU path.

No GPU here, so the kernels' per-thread bodies (declared __host__ __device__ in
kernels/quantize_cuda.cu) are replayed on the CPU by a small host harness that mimics the launch
grid and the fixed-order shared-memory reductions.  When torch has CUDA and a GPU, the real
extension is also compared against the CPU path.  Tests skip cleanly when nvcc is absent.
"""
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from gsz.decoder.quant import MAX_BITS
from gsz.kernels import quantize_cuda
from gsz.kernels.quantize import quantize_all_bits, quantize_groups

NVCC = shutil.which("nvcc")
needs_nvcc = pytest.mark.skipif(NVCC is None, reason="nvcc not on PATH")

HARNESS = r"""
#include "@CU@"
#include <cstdio>
#include <cstdint>
#include <vector>

// Replays the launches of gsz_quant_minmax / gsz_quant_loss / gsz_quant_symbols on the host:
// same grid, same per-thread bodies, same reduction order.
int main(int argc, char** argv) {
    FILE* f = fopen(argv[1], "rb");
    int32_t C, B, bit_lo, bit_hi; int64_t L;
    if (fread(&C, 4, 1, f) != 1 || fread(&L, 8, 1, f) != 1 || fread(&B, 4, 1, f) != 1 ||
        fread(&bit_lo, 4, 1, f) != 1 || fread(&bit_hi, 4, 1, f) != 1) return 2;
    std::vector<float> x(C * L); std::vector<int> bits(C * B);
    if (fread(x.data(), 4, x.size(), f) != x.size() || fread(bits.data(), 4, bits.size(), f) != bits.size()) return 3;
    fclose(f);
    int G = C * B, tiles = gsz_quant_tiles(L, B);
    std::vector<float> pmin(G * tiles), pmax(G * tiles), mins(G), maxs(G);
    float smin[GSZ_THREADS], smax[GSZ_THREADS];
    for (long long gt = 0; gt < (long long)G * tiles; ++gt) {
        for (int tid = 0; tid < GSZ_THREADS; ++tid) gsz_minmax_thread(x.data(), L, B, tiles, gt, tid, &smin[tid], &smax[tid]);
        for (int w = GSZ_THREADS / 2; w > 0; w >>= 1)
            for (int tid = 0; tid < w; ++tid) { smin[tid] = fminf(smin[tid], smin[tid + w]); smax[tid] = fmaxf(smax[tid], smax[tid + w]); }
        pmin[gt] = smin[0]; pmax[gt] = smax[0];
    }
    for (int g = 0; g < G; ++g) {
        float a = INFINITY, z = -INFINITY;
        for (int t = 0; t < tiles; ++t) { a = fminf(a, pmin[(long long)g * tiles + t]); z = fmaxf(z, pmax[(long long)g * tiles + t]); }
        if (a > z) { a = 0.0f; z = 0.0f; }
        mins[g] = a; maxs[g] = z;
    }
    int nq = bit_hi - bit_lo + 1;
    std::vector<double> partial((long long)G * tiles * GSZ_MAX_BITS), loss(G * GSZ_MAX_BITS);
    static double red[GSZ_MAX_BITS][GSZ_THREADS];
    for (long long gt = 0; gt < (long long)G * tiles; ++gt) {
        int g = (int)(gt / tiles);
        double steps[GSZ_MAX_BITS];
        for (int j = 0; j < nq; ++j) steps[j] = gsz_step(mins[g], maxs[g], bit_lo + j);
        for (int tid = 0; tid < GSZ_THREADS; ++tid) {
            double acc[GSZ_MAX_BITS];
            gsz_loss_thread(x.data(), L, B, tiles, gt, tid, mins[g], steps, bit_lo, nq, acc);
            for (int j = 0; j < GSZ_MAX_BITS; ++j) red[j][tid] = acc[j];
        }
        for (int w = GSZ_THREADS / 2; w > 0; w >>= 1)
            for (int tid = 0; tid < w; ++tid)
                for (int j = 0; j < GSZ_MAX_BITS; ++j) red[j][tid] += red[j][tid + w];
        for (int j = 0; j < GSZ_MAX_BITS; ++j) partial[gt * GSZ_MAX_BITS + j] = red[j][0];
    }
    for (int g = 0; g < G; ++g)
        for (int q = 1; q <= GSZ_MAX_BITS; ++q) {
            double sum = 0.0;
            if (q < bit_lo || q > bit_hi) sum = INFINITY;
            else for (int t = 0; t < tiles; ++t) sum += partial[((long long)g * tiles + t) * GSZ_MAX_BITS + (q - bit_lo)];
            loss[g * GSZ_MAX_BITS + q - 1] = sum;
        }
    std::vector<int> sym(C * L, -1);
    for (long long gt = 0; gt < (long long)G * tiles; ++gt)
        for (int tid = 0; tid < GSZ_THREADS; ++tid)
            gsz_symbols_thread(x.data(), L, B, tiles, gt, tid, mins.data(), maxs.data(), bits.data(), sym.data());
    FILE* o = fopen(argv[2], "wb");
    fwrite(mins.data(), 4, G, o); fwrite(maxs.data(), 4, G, o);
    fwrite(loss.data(), 8, loss.size(), o); fwrite(sym.data(), 4, sym.size(), o);
    fclose(o);
    return 0;
}
"""

CU = Path(quantize_cuda.CU_SOURCE)


@needs_nvcc
def test_cu_compiles_for_sm90(tmp_path):
    r = subprocess.run([NVCC, "-c", "-arch=sm_90", "--fmad=false", str(CU), "-o", str(tmp_path / "q.o")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "q.o").stat().st_size > 0


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    if NVCC is None:
        pytest.skip("nvcc not on PATH")
    d = tmp_path_factory.mktemp("cuda_harness")
    src = d / "harness.cu"
    src.write_text(HARNESS.replace("@CU@", str(CU)))
    exe = d / "harness"
    r = subprocess.run([NVCC, "-O2", "--fmad=false", str(src), "-o", str(exe)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return exe


def run_harness(exe, tmp_path, x, num_blocks, bits, bit_lo=1, bit_hi=16):
    c, length = x.shape
    inp, out = tmp_path / "in.bin", tmp_path / "out.bin"
    with open(inp, "wb") as f:
        f.write(np.array([c], "<i4").tobytes() + np.array([length], "<i8").tobytes()
                + np.array([num_blocks, bit_lo, bit_hi], "<i4").tobytes())
        f.write(np.ascontiguousarray(x, "<f4").tobytes() + np.ascontiguousarray(bits, "<i4").tobytes())
    r = subprocess.run([str(exe), str(inp), str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    raw = out.read_bytes()
    g = c * num_blocks
    mins = np.frombuffer(raw, "<f4", g, 0).reshape(c, num_blocks)
    maxs = np.frombuffer(raw, "<f4", g, 4 * g).reshape(c, num_blocks)
    loss = np.frombuffer(raw, "<f8", g * MAX_BITS, 8 * g).reshape(c, num_blocks, MAX_BITS)
    sym = np.frombuffer(raw, "<i4", c * length, 8 * g + 8 * g * MAX_BITS).reshape(c, length)
    return mins, maxs, loss, sym


@pytest.mark.parametrize("length,num_blocks,bit_lo,bit_hi", [(9001, 7, 1, 16), (12_000, 3, 2, 12), (5, 8, 1, 16)])
def test_kernel_bodies_match_cpu_path(harness, tmp_path, sample_sh3, length, num_blocks, bit_lo, bit_hi):
    # Real values: opacity logits, log-scales and colour of the SH3 sample, tiled to `length`.
    c = sample_sh3
    base = np.concatenate([c.opacities[None], c.scales.T, c.sh_dc.T, c.sh_rest[:, :3, 0].T]).astype(np.float32)
    x = np.ascontiguousarray(np.resize(base, (base.shape[0], length)))
    bits = np.random.default_rng(length).integers(bit_lo, bit_hi + 1, (x.shape[0], num_blocks))
    mins, maxs, loss, sym = run_harness(harness, tmp_path, x, num_blocks, bits, bit_lo, bit_hi)
    fn, mins_c, maxs_c, loss_c = quantize_all_bits(x, num_blocks, (bit_lo, bit_hi), device="cpu")
    assert np.array_equal(mins, mins_c) and np.array_equal(maxs, maxs_c)
    assert np.array_equal(np.isinf(loss), np.isinf(loss_c))
    fin = np.isfinite(loss_c)
    assert np.allclose(loss[fin], loss_c[fin], rtol=1e-10, atol=1e-300)
    assert np.array_equal(sym, fn(bits))


@pytest.mark.skipif(not quantize_cuda.cuda_possible(), reason="no CUDA GPU visible to torch")
def test_gpu_extension_matches_cpu(sample_sh3):
    x = np.resize(sample_sh3.scales.T.astype(np.float32), (3, 100_003))
    bits = np.random.default_rng(0).integers(1, 17, (3, 80))
    fn_g, mins_g, maxs_g, loss_g = quantize_all_bits(x, 80, device="cuda")
    fn_c, mins_c, maxs_c, loss_c = quantize_all_bits(x, 80, device="cpu")
    assert np.array_equal(mins_g, mins_c) and np.array_equal(maxs_g, maxs_c)
    assert np.allclose(loss_g, loss_c, rtol=1e-10)
    assert np.array_equal(fn_g(bits), fn_c(bits))
    assert np.array_equal(quantize_groups(x, 80, bits, device="cuda")[0], fn_c(bits))
    _, _, _, loss_g2 = quantize_all_bits(x, 80, device="cuda")
    assert np.array_equal(loss_g, loss_g2)                 # deterministic reductions
