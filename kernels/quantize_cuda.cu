// gsz group-wise min-max quantiser: CUDA kernels (plain CUDA C++, no torch headers).
//
// Compiles stand-alone (`nvcc -c -arch=sm_90 quantize_cuda.cu`, checked by
// tests/test_cuda_kernel.py); the torch binding lives in gsz/kernels/quantize_cuda.py, which
// compiles this file together with a few lines of C++ glue via torch.utils.cpp_extension.
//
// Data: x is a contiguous float32 [C, L] matrix.  Channel c is cut into B contiguous blocks by
// the normative split (first L mod B blocks have floor(L/B)+1 elements, the rest floor(L/B));
// group g = c * B + b.  Quantiser (normative, gsz/decoder/quant.py):
//     m, M  = float32 min / max of the group
//     s     = (double(M) - double(m)) / (2^q - 1)   if M > m, else 1.0
//     k     = clamp(rint((double(x) - double(m)) / s), 0, 2^q - 1)      (rint: half to even)
//     x_hat = double(m) + s * k
//
// Work split: every group is cut into `tiles` tiles of TILE elements (tiles = ceil(max block
// length / TILE), the same for all groups; tiles past a group's end contribute identities).
// A CUDA block handles one (group, tile) and writes one partial result; a second kernel folds
// the partials of each group in tile order.  There are no atomics and every reduction has a
// fixed order, so results are bit-reproducible run to run for the same shapes.
//
// Build with --fmad=false so x_hat / the error are formed by separate multiply and subtract
// like the CPU path (the loss then agrees with the CPU table to float64 summation-order noise;
// the symbols are bit-identical regardless, they involve no multiply-add).

#include <cuda_runtime.h>
#include <math.h>

#define GSZ_THREADS 256
#define GSZ_PER_THREAD 16
#define GSZ_TILE (GSZ_THREADS * GSZ_PER_THREAD)
#define GSZ_MAX_BITS 16

struct GszBlockSpan {
    long long start;   // element offset inside the channel
    long long length;  // elements in the block
};

__host__ __device__ inline GszBlockSpan gsz_block_span(long long L, int B, int b) {
    long long base = L / B;
    long long extra = L % B;
    GszBlockSpan sp;
    if (b < extra) {
        sp.start = (long long)b * (base + 1);
        sp.length = base + 1;
    } else {
        sp.start = extra * (base + 1) + (long long)(b - extra) * base;
        sp.length = base;
    }
    return sp;
}

__host__ __device__ inline double gsz_step(float mn, float mx, int q) {
    double span = (double)mx - (double)mn;
    double levels = (double)((1 << q) - 1);
    return span > 0.0 ? span / levels : 1.0;
}

__host__ __device__ inline double gsz_symbol(float x, float mn, double s, double levels) {
    double k = rint(((double)x - (double)mn) / s);
    return fmin(fmax(k, 0.0), levels);
}

// ---- min / max -------------------------------------------------------------------------

// Per-thread part of gsz_minmax_partial (host+device so tests can run it on the CPU).
__host__ __device__ inline void gsz_minmax_thread(const float* x, long long L, int B, int tiles,
                                                  long long gt, int tid, float* vmin, float* vmax) {
    int g = (int)(gt / tiles), t = (int)(gt % tiles);   // gt = (group, tile) index
    int c = g / B, b = g % B;
    GszBlockSpan sp = gsz_block_span(L, B, b);
    const float* base = x + (long long)c * L + sp.start;
    long long lo = (long long)t * GSZ_TILE;
    long long hi = lo + GSZ_TILE < sp.length ? lo + GSZ_TILE : sp.length;
    float a = INFINITY, z = -INFINITY;
    for (long long i = lo + tid; i < hi; i += GSZ_THREADS) {
        float v = base[i];
        a = fminf(a, v);
        z = fmaxf(z, v);
    }
    *vmin = a;
    *vmax = z;
}

__global__ void gsz_minmax_partial(const float* __restrict__ x, long long L, int B, int tiles,
                                   float* __restrict__ part_min, float* __restrict__ part_max) {
    __shared__ float smin[GSZ_THREADS];
    __shared__ float smax[GSZ_THREADS];
    long long gt = blockIdx.x;
    float vmin, vmax;
    gsz_minmax_thread(x, L, B, tiles, gt, threadIdx.x, &vmin, &vmax);
    smin[threadIdx.x] = vmin;
    smax[threadIdx.x] = vmax;
    __syncthreads();
    for (int w = GSZ_THREADS / 2; w > 0; w >>= 1) {
        if (threadIdx.x < w) {
            smin[threadIdx.x] = fminf(smin[threadIdx.x], smin[threadIdx.x + w]);
            smax[threadIdx.x] = fmaxf(smax[threadIdx.x], smax[threadIdx.x + w]);
        }
        __syncthreads();
    }
    if (threadIdx.x == 0) {
        part_min[gt] = smin[0];
        part_max[gt] = smax[0];
    }
}

__global__ void gsz_minmax_final(int G, int tiles, const float* __restrict__ part_min,
                                 const float* __restrict__ part_max, float* __restrict__ mins,
                                 float* __restrict__ maxs) {
    int g = blockIdx.x * blockDim.x + threadIdx.x;
    if (g >= G) return;
    float vmin = INFINITY, vmax = -INFINITY;
    for (int t = 0; t < tiles; ++t) {
        vmin = fminf(vmin, part_min[(long long)g * tiles + t]);
        vmax = fmaxf(vmax, part_max[(long long)g * tiles + t]);
    }
    if (vmin > vmax) { vmin = 0.0f; vmax = 0.0f; }   // empty group
    mins[g] = vmin;
    maxs[g] = vmax;
}

// ---- loss table for all bit-widths ------------------------------------------------------

// Per-thread part of gsz_loss_partial (host+device so tests can run it on the CPU): the
// squared errors of this thread's elements of tile t of group g, for q = bit_lo + j.
__host__ __device__ inline void gsz_loss_thread(const float* x, long long L, int B, int tiles,
                                                long long gt, int tid, float mn, const double* steps,
                                                int bit_lo, int nq, double* acc) {
    int g = (int)(gt / tiles), t = (int)(gt % tiles);
    int c = g / B, b = g % B;
    GszBlockSpan sp = gsz_block_span(L, B, b);
    const float* base = x + (long long)c * L + sp.start;
    long long lo = (long long)t * GSZ_TILE;
    long long hi = lo + GSZ_TILE < sp.length ? lo + GSZ_TILE : sp.length;
    for (int j = 0; j < GSZ_MAX_BITS; ++j) acc[j] = 0.0;
    for (long long i = lo + tid; i < hi; i += GSZ_THREADS) {
        double d = (double)base[i] - (double)mn;
        for (int j = 0; j < GSZ_MAX_BITS; ++j) {
            if (j < nq) {
                double s = steps[j];
                double levels = (double)((1 << (bit_lo + j)) - 1);
                double k = fmin(fmax(rint(d / s), 0.0), levels);
                double e = d - k * s;
                acc[j] += e * e;
            }
        }
    }
}

__global__ void gsz_loss_partial(const float* __restrict__ x, long long L, int B, int tiles,
                                 const float* __restrict__ mins, const float* __restrict__ maxs,
                                 int bit_lo, int bit_hi, double* __restrict__ partial) {
    __shared__ double red[GSZ_MAX_BITS][GSZ_THREADS];
    __shared__ double steps[GSZ_MAX_BITS];
    long long gt = blockIdx.x;
    int g = (int)(gt / tiles);
    int nq = bit_hi - bit_lo + 1;
    float mn = mins[g], mx = maxs[g];
    if (threadIdx.x < nq) steps[threadIdx.x] = gsz_step(mn, mx, bit_lo + threadIdx.x);
    __syncthreads();
    double acc[GSZ_MAX_BITS];
    gsz_loss_thread(x, L, B, tiles, gt, threadIdx.x, mn, steps, bit_lo, nq, acc);
#pragma unroll
    for (int j = 0; j < GSZ_MAX_BITS; ++j) red[j][threadIdx.x] = acc[j];
    __syncthreads();
    // Fixed-order tree reduction (tests/test_cuda_kernel.py replays exactly this order).
    for (int w = GSZ_THREADS / 2; w > 0; w >>= 1) {
        if (threadIdx.x < w) {
#pragma unroll
            for (int j = 0; j < GSZ_MAX_BITS; ++j) red[j][threadIdx.x] += red[j][threadIdx.x + w];
        }
        __syncthreads();
    }
    if (threadIdx.x < GSZ_MAX_BITS) partial[gt * GSZ_MAX_BITS + threadIdx.x] = red[threadIdx.x][0];
}

// loss[g, q-1] for q in [bit_lo, bit_hi]; other entries +inf.
__global__ void gsz_loss_final(int G, int tiles, int bit_lo, int bit_hi,
                               const double* __restrict__ partial, double* __restrict__ loss) {
    long long idx = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (idx >= (long long)G * GSZ_MAX_BITS) return;
    int g = (int)(idx / GSZ_MAX_BITS), q = (int)(idx % GSZ_MAX_BITS) + 1;
    if (q < bit_lo || q > bit_hi) { loss[idx] = INFINITY; return; }
    int j = q - bit_lo;
    double sum = 0.0;
    for (int t = 0; t < tiles; ++t) sum += partial[((long long)g * tiles + t) * GSZ_MAX_BITS + j];
    loss[idx] = sum;
}

// ---- symbols for a chosen allocation ----------------------------------------------------

// Per-thread body of gsz_symbols (host+device so tests can run it on the CPU).
__host__ __device__ inline void gsz_symbols_thread(const float* x, long long L, int B, int tiles,
                                                   long long gt, int tid, const float* mins,
                                                   const float* maxs, const int* bits, int* symbols) {
    int g = (int)(gt / tiles), t = (int)(gt % tiles);
    int c = g / B, b = g % B;
    int q = bits[g];
    float mn = mins[g];
    double s = gsz_step(mn, maxs[g], q);
    double levels = (double)((1 << q) - 1);
    GszBlockSpan sp = gsz_block_span(L, B, b);
    long long off = (long long)c * L + sp.start;
    long long lo = (long long)t * GSZ_TILE;
    long long hi = lo + GSZ_TILE < sp.length ? lo + GSZ_TILE : sp.length;
    for (long long i = lo + tid; i < hi; i += GSZ_THREADS)
        symbols[off + i] = (int)gsz_symbol(x[off + i], mn, s, levels);
}

__global__ void gsz_symbols(const float* __restrict__ x, long long L, int B, int tiles,
                            const float* __restrict__ mins, const float* __restrict__ maxs,
                            const int* __restrict__ bits, int* __restrict__ symbols) {
    gsz_symbols_thread(x, L, B, tiles, blockIdx.x, threadIdx.x, mins, maxs, bits, symbols);
}

// ---- host launchers (C ABI; `stream` is a cudaStream_t, 0 = default stream) ----------------

extern "C" {

// Tiles per group for a channel of length L cut into B blocks (at least 1).
int gsz_quant_tiles(long long L, int B) {
    long long longest = L / B + (L % B ? 1 : 0);
    long long t = (longest + GSZ_TILE - 1) / GSZ_TILE;
    return t > 0 ? (int)t : 1;
}

// part_min / part_max: scratch float32 [C*B*tiles]; mins / maxs: float32 [C*B].
int gsz_quant_minmax(const float* x, int C, long long L, int B, int tiles, float* part_min,
                     float* part_max, float* mins, float* maxs, void* stream) {
    cudaStream_t st = (cudaStream_t)stream;
    int G = C * B;
    long long nblk = (long long)G * tiles;
    if (nblk == 0) return 0;
    gsz_minmax_partial<<<(unsigned)nblk, GSZ_THREADS, 0, st>>>(x, L, B, tiles, part_min, part_max);
    gsz_minmax_final<<<(G + 255) / 256, 256, 0, st>>>(G, tiles, part_min, part_max, mins, maxs);
    return (int)cudaGetLastError();
}

// partial: scratch float64 [C*B*tiles*16]; loss: float64 [C*B*16].
int gsz_quant_loss(const float* x, int C, long long L, int B, int tiles, const float* mins,
                   const float* maxs, int bit_lo, int bit_hi, double* partial, double* loss,
                   void* stream) {
    cudaStream_t st = (cudaStream_t)stream;
    int G = C * B;
    long long nblk = (long long)G * tiles;
    if (nblk == 0) return 0;
    if (bit_lo < 1 || bit_hi > GSZ_MAX_BITS || bit_lo > bit_hi) return (int)cudaErrorInvalidValue;
    gsz_loss_partial<<<(unsigned)nblk, GSZ_THREADS, 0, st>>>(x, L, B, tiles, mins, maxs, bit_lo,
                                                              bit_hi, partial);
    long long n = (long long)G * GSZ_MAX_BITS;
    gsz_loss_final<<<(unsigned)((n + 255) / 256), 256, 0, st>>>(G, tiles, bit_lo, bit_hi, partial,
                                                                loss);
    return (int)cudaGetLastError();
}

// bits: int32 [C*B] in 1..16; symbols: int32 [C*L].
int gsz_quant_symbols(const float* x, int C, long long L, int B, int tiles, const float* mins,
                      const float* maxs, const int* bits, int* symbols, void* stream) {
    cudaStream_t st = (cudaStream_t)stream;
    long long nblk = (long long)C * B * tiles;
    if (nblk == 0) return 0;
    gsz_symbols<<<(unsigned)nblk, GSZ_THREADS, 0, st>>>(x, L, B, tiles, mins, maxs, bits, symbols);
    return (int)cudaGetLastError();
}

}  // extern "C"
