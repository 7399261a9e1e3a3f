"""Run-time loader and torch binding of ``quantize_cuda.cu`` (the CUDA quantiser).

The .cu file is plain CUDA with a C ABI (no torch headers, so `nvcc -c` alone can check it);
the few lines of C++ glue below turn torch tensors into raw pointers plus the current CUDA
stream.  The extension is compiled with torch.utils.cpp_extension.load_inline the first time
it is needed, and ONLY when torch was built with CUDA and a GPU is visible -- importing this
module never compiles anything.  A failed build is reported once as a warning and the
dispatcher (``gsz.kernels.quantize``) falls back to the CPU path.
"""
from __future__ import annotations

import functools
import warnings
from pathlib import Path

import torch

CU_SOURCE = Path(__file__).with_name("quantize_cuda.cu")

_CPP_GLUE = r"""
#include <torch/extension.h>
#include <ATen/cuda/CUDAContext.h>

extern "C" {
int gsz_quant_tiles(long long L, int B);
int gsz_quant_minmax(const float* x, int C, long long L, int B, int tiles, float* part_min,
                     float* part_max, float* mins, float* maxs, void* stream);
int gsz_quant_loss(const float* x, int C, long long L, int B, int tiles, const float* mins,
                   const float* maxs, int bit_lo, int bit_hi, double* partial, double* loss,
                   void* stream);
int gsz_quant_symbols(const float* x, int C, long long L, int B, int tiles, const float* mins,
                      const float* maxs, const int* bits, int* symbols, void* stream);
}

static void check_x(const torch::Tensor& x) {
  TORCH_CHECK(x.is_cuda() && x.scalar_type() == torch::kFloat32 && x.dim() == 2 && x.is_contiguous(),
              "x must be a contiguous float32 CUDA tensor [C, L]");
}

static void check_rc(int rc, const char* what) {
  TORCH_CHECK(rc == 0, what, " failed with CUDA error ", rc);
}

std::vector<torch::Tensor> minmax(torch::Tensor x, int64_t B) {
  check_x(x);
  int C = (int)x.size(0); long long L = x.size(1);
  int tiles = gsz_quant_tiles(L, (int)B);
  auto f = x.options();
  auto pmin = torch::empty({C * B * tiles}, f), pmax = torch::empty({C * B * tiles}, f);
  auto mins = torch::empty({C, B}, f), maxs = torch::empty({C, B}, f);
  check_rc(gsz_quant_minmax(x.data_ptr<float>(), C, L, (int)B, tiles, pmin.data_ptr<float>(),
                            pmax.data_ptr<float>(), mins.data_ptr<float>(), maxs.data_ptr<float>(),
                            (void*)at::cuda::getCurrentCUDAStream().stream()), "gsz_quant_minmax");
  return {mins, maxs};
}

torch::Tensor loss(torch::Tensor x, int64_t B, torch::Tensor mins, torch::Tensor maxs,
                   int64_t bit_lo, int64_t bit_hi) {
  check_x(x);
  int C = (int)x.size(0); long long L = x.size(1);
  int tiles = gsz_quant_tiles(L, (int)B);
  auto d = x.options().dtype(torch::kFloat64);
  auto partial = torch::empty({C * B * tiles * 16}, d);
  auto out = torch::empty({C, B, 16}, d);
  check_rc(gsz_quant_loss(x.data_ptr<float>(), C, L, (int)B, tiles, mins.data_ptr<float>(),
                          maxs.data_ptr<float>(), (int)bit_lo, (int)bit_hi, partial.data_ptr<double>(),
                          out.data_ptr<double>(), (void*)at::cuda::getCurrentCUDAStream().stream()),
           "gsz_quant_loss");
  return out;
}

torch::Tensor symbols(torch::Tensor x, int64_t B, torch::Tensor mins, torch::Tensor maxs,
                      torch::Tensor bits) {
  check_x(x);
  int C = (int)x.size(0); long long L = x.size(1);
  int tiles = gsz_quant_tiles(L, (int)B);
  auto out = torch::empty({C, L}, x.options().dtype(torch::kInt32));
  check_rc(gsz_quant_symbols(x.data_ptr<float>(), C, L, (int)B, tiles, mins.data_ptr<float>(),
                             maxs.data_ptr<float>(), bits.data_ptr<int>(), out.data_ptr<int>(),
                             (void*)at::cuda::getCurrentCUDAStream().stream()), "gsz_quant_symbols");
  return out;
}
"""


def cuda_possible() -> bool:
    """True when torch has CUDA support and a GPU is visible (no compilation attempted)."""
    return torch.version.cuda is not None and torch.cuda.is_available()


@functools.lru_cache(maxsize=1)
def _extension():
    from torch.utils.cpp_extension import load_inline
    return load_inline(
        name="gsz_quantize_cuda",
        cpp_sources=[_CPP_GLUE],
        cuda_sources=[CU_SOURCE.read_text()],
        functions=["minmax", "loss", "symbols"],
        extra_cuda_cflags=["--fmad=false", "-O3"],
        verbose=False,
    )


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """True when the CUDA extension can be used (GPU present and the build succeeds)."""
    if not cuda_possible():
        return False
    try:
        _extension()
        return True
    except Exception as exc:  # build toolchain missing or broken: fall back to CPU, say why once
        warnings.warn(f"gsz CUDA quantiser unavailable, using the CPU path: {exc}", RuntimeWarning)
        return False


def _dev(t: torch.Tensor, dtype=None) -> torch.Tensor:
    return t.to(device="cuda", dtype=dtype or t.dtype).contiguous()


def minmax(x: torch.Tensor, num_blocks: int) -> tuple[torch.Tensor, torch.Tensor]:
    """float32 [C, B] group min / max on the GPU (x: float32 [C, L])."""
    mins, maxs = _extension().minmax(_dev(x, torch.float32), int(num_blocks))
    return mins, maxs


def minmax_and_loss(x: torch.Tensor, num_blocks: int, bit_lo: int, bit_hi: int):
    """(mins, maxs, loss float64 [C, B, 16]) on the GPU; same contract as the CPU path."""
    xd = _dev(x, torch.float32)
    ext = _extension()
    mins, maxs = ext.minmax(xd, int(num_blocks))
    loss = ext.loss(xd, int(num_blocks), mins, maxs, int(bit_lo), int(bit_hi))
    return mins, maxs, loss


def quantize(x: torch.Tensor, num_blocks: int, bits: torch.Tensor, mins: torch.Tensor,
             maxs: torch.Tensor) -> torch.Tensor:
    """int32 [C, L] symbols on the GPU for bits int [C, B] (values 1..16)."""
    return _extension().symbols(_dev(x, torch.float32), int(num_blocks), _dev(mins, torch.float32),
                                _dev(maxs, torch.float32), _dev(bits, torch.int32))
