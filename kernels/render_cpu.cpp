// CPU tile rasteriser for gsz.evaluation.render (graphdeco 3DGS forward semantics).
//
// Built at run time by torch.utils.cpp_extension.load() from gsz/evaluation/render.py; the
// pure-torch rasteriser there is the reference this kernel is tested against.
//
// Two entry points, both mirroring the pure-torch reference in render.py step by step:
//   preprocess(...)  per-Gaussian projection, EWA covariance, SH colour, tile rectangle and a
//                    conservative pixel box; returns per-Gaussian arrays plus the front-to-back
//                    order of the visible ones.
//   sh_colors(...)   the SH colours preprocess makes, of a row range (for an SH rest that is
//                    made a row range at a time: render.py's chunked colour pass).
//   rasterize(...)   tile binning + per-pixel compositing of those arrays:
//   means   [N, 2] f32   pixel-space centre (pixel (px, py) is evaluated at (px, py))
//   conic   [N, 3] f32   inverse 2D covariance (a, b, c): power = -0.5(a dx^2 + c dy^2) - b dx dy
//   opac    [N]    f32   sigmoid(opacity)
//   colors  [N, 3] f32   SH colour (+0.5, clamped at 0)
//   boxes   [N, 4] i16   pixel box (x0, y0, x1, y1), x1/y1 exclusive: a conservative box
//                        outside of which alpha < 1/255 everywhere (so skipping it is exact), cut
//                        to the graphdeco tile rectangle (the pixels graphdeco lets the Gaussian
//                        reach); empty = never drawn. Its tiles are the tiles binned into.
//   order   [M]    i32   visible Gaussians (rows), front to back
// Outputs: image [H, W, 3] f32 (without background), trans [H, W] f32 (final T),
//          importance [N] f64 (sum over pixels of alpha*T) when want_importance.
//
// Determinism: tiles are distributed over threads dynamically, but every tile writes only its
// own pixels and its own per-entry importance slots; the per-Gaussian reduction afterwards runs
// sequentially in (tile, depth) order. The result does not depend on the thread count.
// Compiled with -ffp-contract=off so float32 arithmetic rounds exactly like the torch reference.
#include <torch/extension.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <vector>

namespace {
constexpr int BLOCK = 16;
constexpr int BLOCK_PIX = BLOCK * BLOCK;
}  // namespace

// Runs f(begin, end) over [0, n) in contiguous chunks on up to num_threads threads. Every index
// is written by exactly one thread, so results do not depend on the thread count.
template <typename F>
static void parallel_chunks(int64_t n, int64_t num_threads, F f) {
  const int64_t nt = std::max<int64_t>(1, std::min<int64_t>(num_threads, (n + 4095) / 4096));
  if (nt == 1) { f(int64_t(0), n); return; }
  std::vector<std::thread> pool;
  const int64_t chunk = (n + nt - 1) / nt;
  for (int64_t i = 0; i < nt; ++i) {
    const int64_t b = i * chunk, e = std::min(n, b + chunk);
    if (b < e) pool.emplace_back(f, b, e);
  }
  for (auto& th : pool) th.join();
}

std::vector<torch::Tensor> rasterize(torch::Tensor means, torch::Tensor conic, torch::Tensor opac,
                                     torch::Tensor colors, torch::Tensor boxes,
                                     torch::Tensor order, int64_t width,
                                     int64_t height, bool want_importance, int64_t num_threads) {
  TORCH_CHECK(means.dtype() == torch::kFloat32 && conic.dtype() == torch::kFloat32 &&
                  opac.dtype() == torch::kFloat32 && colors.dtype() == torch::kFloat32,
              "float32 inputs expected");
  TORCH_CHECK(boxes.dtype() == torch::kInt16, "int16 boxes expected");
  TORCH_CHECK(order.dtype() == torch::kInt32, "int32 order expected");
  order = order.contiguous();
  means = means.contiguous();
  conic = conic.contiguous();
  opac = opac.contiguous();
  colors = colors.contiguous();
  boxes = boxes.contiguous();
  const int64_t N = means.size(0);      // rows of the per-Gaussian arrays
  const int64_t M = order.size(0);      // visible Gaussians, front to back
  const int32_t* ordp = order.data_ptr<int32_t>();
  TORCH_CHECK(N < (int64_t(1) << 31), "too many Gaussians");
  const int W = static_cast<int>(width), H = static_cast<int>(height);
  const int gx = (W + BLOCK - 1) / BLOCK, gy = (H + BLOCK - 1) / BLOCK;
  const int64_t ntiles = static_cast<int64_t>(gx) * gy;

  const float* mp = means.data_ptr<float>();
  const float* cp = conic.data_ptr<float>();
  const float* op = opac.data_ptr<float>();
  const float* colp = colors.data_ptr<float>();
  const int16_t* bp = boxes.data_ptr<int16_t>();
  // The tiles a box meets (x0, y0, x1, y1), none for an empty box: as the box lies within the
  // graphdeco rectangle, those of the rectangle that can receive a contribution.
  auto tiles = [bp](int64_t g, int t[4]) {
    const int16_t* b = bp + 4 * g;
    if (b[2] > b[0] && b[3] > b[1]) {
      t[0] = b[0] / BLOCK; t[1] = b[1] / BLOCK;
      t[2] = (b[2] - 1) / BLOCK + 1; t[3] = (b[3] - 1) / BLOCK + 1;
    } else {
      t[0] = t[1] = t[2] = t[3] = 0;
    }
  };

  // Binning: counting sort keyed by tile; filling in depth order keeps each list sorted
  // front-to-back with ties in index order (what graphdeco's stable radix sort gives). Each
  // thread counts and fills one contiguous stretch of the order, and a tile's entries from an
  // earlier stretch come first: the lists are the same whatever the thread count.
  const int64_t nst = std::max<int64_t>(1, std::min<int64_t>(num_threads, (M + 65535) / 65536));
  const int64_t stretch = (M + nst - 1) / nst;
  std::vector<int64_t> start(nst * ntiles, 0);    // per stretch: its count, then its first slot
  std::atomic<bool> bad_index(false);
  auto each_stretch = [&](auto f) {
    if (nst == 1) { f(int64_t(0), int64_t(0), M); return; }
    std::vector<std::thread> pool;
    for (int64_t s = 0; s < nst; ++s)
      pool.emplace_back(f, s, s * stretch, std::min(M, (s + 1) * stretch));
    for (auto& th : pool) th.join();
  };
  each_stretch([&](int64_t s, int64_t j0, int64_t j1) {
    int64_t* cnt = start.data() + s * ntiles;
    for (int64_t j = j0; j < j1; ++j) {
      const int64_t g = ordp[j];
      if (g < 0 || g >= N) { bad_index = true; return; }
      int r[4];
      tiles(g, r);
      for (int ty = r[1]; ty < r[3]; ++ty)
        for (int tx = r[0]; tx < r[2]; ++tx) cnt[static_cast<int64_t>(ty) * gx + tx]++;
    }
  });
  TORCH_CHECK(!bad_index, "order index out of range");
  std::vector<int64_t> offsets(ntiles + 1, 0);
  for (int64_t t = 0; t < ntiles; ++t) {
    int64_t at = offsets[t];
    for (int64_t s = 0; s < nst; ++s) {
      const int64_t c = start[s * ntiles + t];
      start[s * ntiles + t] = at;
      at += c;
    }
    offsets[t + 1] = at;
  }
  const int64_t E = offsets[ntiles];
  std::vector<int32_t> entries(E);  // Gaussian row (N < 2^31 is checked)
  each_stretch([&](int64_t s, int64_t j0, int64_t j1) {
    int64_t* fill = start.data() + s * ntiles;
    for (int64_t j = j0; j < j1; ++j) {
      int r[4];
      tiles(ordp[j], r);
      for (int ty = r[1]; ty < r[3]; ++ty)
        for (int tx = r[0]; tx < r[2]; ++tx)
          entries[fill[static_cast<int64_t>(ty) * gx + tx]++] = ordp[j];
    }
  });
  std::vector<int64_t>().swap(start);
  std::vector<double> entry_imp(want_importance ? E : 0, 0.0);

  auto image = torch::zeros({H, W, 3}, torch::kFloat32);
  auto trans = torch::ones({H, W}, torch::kFloat32);
  float* img = image.data_ptr<float>();
  float* trp = trans.data_ptr<float>();

  std::atomic<int64_t> next_tile(0);
  auto worker = [&]() {
    float T[BLOCK_PIX];
    float C[BLOCK_PIX * 3];
    bool done[BLOCK_PIX];
    for (;;) {
      const int64_t tile = next_tile.fetch_add(1);
      if (tile >= ntiles) break;
      const int tyi = static_cast<int>(tile / gx), txi = static_cast<int>(tile % gx);
      const int px0 = txi * BLOCK, py0 = tyi * BLOCK;
      const int px1 = std::min(px0 + BLOCK, W), py1 = std::min(py0 + BLOCK, H);
      const int npix = (px1 - px0) * (py1 - py0);
      for (int i = 0; i < BLOCK_PIX; ++i) { T[i] = 1.0f; done[i] = false; }
      for (int i = 0; i < BLOCK_PIX * 3; ++i) C[i] = 0.0f;
      int ndone = 0;
      for (int64_t e = offsets[tile]; e < offsets[tile + 1] && ndone < npix; ++e) {
        const int64_t g = entries[e];
        const int16_t* b = bp + 4 * g;
        const int bx0 = std::max<int>(px0, b[0]), by0 = std::max<int>(py0, b[1]);
        const int bx1 = std::min<int>(px1, b[2]), by1 = std::min<int>(py1, b[3]);
        if (bx1 <= bx0 || by1 <= by0) continue;
        const float mx = mp[2 * g], my = mp[2 * g + 1];
        const float ca = cp[3 * g], cb = cp[3 * g + 1], cc = cp[3 * g + 2];
        const float o = op[g];
        const float cr = colp[3 * g], cgn = colp[3 * g + 1], cbl = colp[3 * g + 2];
        // Below `faint` o * exp(power) < 1/255 by a 0.1 % margin, far beyond float32 rounding:
        // those pixels (the box's corners outside the alpha ellipse) would be skipped after the
        // exp, so skipping them before it changes nothing (o = 0: +inf, every pixel skipped).
        const float faint = std::log(1.0f / (255.0f * o)) - 1e-3f;
        double acc = 0.0;
        for (int py = by0; py < by1; ++py) {
          const float dy = my - static_cast<float>(py);
          for (int px = bx0; px < bx1; ++px) {
            const int li = (py - py0) * BLOCK + (px - px0);
            if (done[li]) continue;
            const float dx = mx - static_cast<float>(px);
            const float power = -0.5f * (ca * dx * dx + cc * dy * dy) - cb * dx * dy;
            if (power > 0.0f || power < faint) continue;
            const float alpha = std::min(0.99f, o * std::exp(power));
            if (alpha < 1.0f / 255.0f) continue;
            const float t = T[li];
            const float test_t = t * (1.0f - alpha);
            if (test_t < 0.0001f) {
              done[li] = true;
              ++ndone;
              continue;
            }
            C[3 * li] += cr * alpha * t;
            C[3 * li + 1] += cgn * alpha * t;
            C[3 * li + 2] += cbl * alpha * t;
            acc += static_cast<double>(alpha) * static_cast<double>(t);
            T[li] = test_t;
          }
        }
        if (want_importance) entry_imp[e] = acc;
      }
      for (int py = py0; py < py1; ++py)
        for (int px = px0; px < px1; ++px) {
          const int li = (py - py0) * BLOCK + (px - px0);
          const int64_t o = static_cast<int64_t>(py) * W + px;
          img[3 * o] = C[3 * li];
          img[3 * o + 1] = C[3 * li + 1];
          img[3 * o + 2] = C[3 * li + 2];
          trp[o] = T[li];
        }
    }
  };
  const int nt = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(num_threads, ntiles)));
  if (nt == 1) {
    worker();
  } else {
    std::vector<std::thread> pool;
    for (int i = 0; i < nt; ++i) pool.emplace_back(worker);
    for (auto& th : pool) th.join();
  }

  auto importance = torch::zeros({want_importance ? N : 0}, torch::kFloat64);
  if (want_importance) {
    double* ip = importance.data_ptr<double>();
    for (int64_t e = 0; e < E; ++e) ip[entries[e]] += entry_imp[e];  // fixed (tile, depth) order
  }
  return {image, trans, importance};
}

// graphdeco computeColorFromSH's sum for colour channel ch from `res` on (the DC term, or 0):
// rest [K, 3] (coefficient-major, RGB last; K >= (deg+1)^2-1), unit view direction x, y, z.
static inline float sh_sum(const float* rs, int ch, int64_t deg, float x, float y, float z, float res) {
  auto sh = [&](int k) { return rs[3 * k + ch]; };
  if (deg > 0) {
    const float C1 = (float)0.4886025119029199;
    res = res - C1 * y * sh(0) + C1 * z * sh(1) - C1 * x * sh(2);
    if (deg > 1) {
      const float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
      res = res + (float)1.0925484305920792 * xy * sh(3) + (float)-1.0925484305920792 * yz * sh(4) +
            (float)0.31539156525252005 * (2.0f * zz - xx - yy) * sh(5) +
            (float)-1.0925484305920792 * xz * sh(6) + (float)0.5462742152960396 * (xx - yy) * sh(7);
      if (deg > 2) {
        res = res + (float)-0.5900435899266435 * y * (3.0f * xx - yy) * sh(8) +
              (float)2.890611442640554 * xy * z * sh(9) +
              (float)-0.4570457994644658 * y * (4.0f * zz - xx - yy) * sh(10) +
              (float)0.3731763325901154 * z * (2.0f * zz - 3.0f * xx - 3.0f * yy) * sh(11) +
              (float)-0.4570457994644658 * x * (4.0f * zz - xx - yy) * sh(12) +
              (float)1.445305721320277 * z * (xx - yy) * sh(13) +
              (float)-0.5900435899266435 * x * (xx - 3.0f * yy) * sh(14);
      }
    }
  }
  return res;
}

// graphdeco computeColorFromSH + 0.5, clamped at 0, of one Gaussian: position p [3], dc [3], rest
// [K, 3], camera centre campos [3] -> out [3]. `turn` (nullptr, or a row-major [3, 3]): the rest
// is held in another colour space, so its view-dependent sum v is turned to v @ turn before the
// DC term is added (render.py's ColourRows; the torch path's order). One definition for
// preprocess and sh_colors, so both round alike.
static inline void sh_color(const float* p, const float* dc, const float* rs, int64_t deg,
                            const float campos[3], const float* turn, float* out) {
  float dx = p[0] - campos[0], dy = p[1] - campos[1], dz = p[2] - campos[2];
  const float dn = std::sqrt(dx * dx + dy * dy + dz * dz);
  const float x = dx / dn, y = dy / dn, z = dz / dn;
  const float C0 = (float)0.28209479177387814;
  if (turn == nullptr || rs == nullptr || deg == 0) {
    for (int ch = 0; ch < 3; ++ch)
      out[ch] = std::max(sh_sum(rs, ch, deg, x, y, z, C0 * dc[ch]) + 0.5f, 0.0f);
    return;
  }
  float v[3];
  for (int ch = 0; ch < 3; ++ch) v[ch] = sh_sum(rs, ch, deg, x, y, z, 0.0f);
  for (int ch = 0; ch < 3; ++ch) {
    const float view = v[0] * turn[ch] + v[1] * turn[3 + ch] + v[2] * turn[6 + ch];
    out[ch] = std::max(C0 * dc[ch] + view + 0.5f, 0.0f);
  }
}

// The [3, 3] colour turn of an SH rest (render.py's ColourRows), or nullptr for an empty tensor.
static const float* colour_turn(const torch::Tensor& turn) {
  if (turn.numel() == 0) return nullptr;
  TORCH_CHECK(turn.dtype() == torch::kFloat32 && turn.numel() == 9 && turn.is_contiguous(),
              "colour turn: 9 contiguous float32 expected");
  return turn.data_ptr<float>();
}

// Camera centre -R^T t, as float (render.py: torch.from_numpy(camera.center).float()).
static void camera_centre(const double* cm, float campos[3]) {
  for (int i = 0; i < 3; ++i)
    campos[i] = (float)(-(cm[0 + i] * cm[9] + cm[3 + i] * cm[10] + cm[6 + i] * cm[11]));
}

// Per-Gaussian preprocessing, the same steps as render.py::_preprocess (see there for the
// graphdeco references). Returns the per-Gaussian arrays means, conic, opac, colors, boxes (N
// rows; rows of culled Gaussians are garbage) and `order` [M] int32: the visible Gaussians
// sorted front to back, ties by index. The arrays are as narrow as rasterize allows (int16
// boxes, int32 order, no visibility mask: a culled row keeps depth 0): at 6 M Gaussians a
// render's arrays are a search's memory peak.
//   positions [N,3], log_scales [N,3], rotations [N,4] (w,x,y,z), opacity_logits [N],
//   sh_dc [N,3], sh_rest [N,K,3] (K >= (deg+1)^2-1), turn (empty, or [3,3] f32: sh_color's),
//   cam = [R (9, row-major), t (3), fx, fy, cx, cy] float64.
std::vector<torch::Tensor> preprocess(torch::Tensor positions, torch::Tensor log_scales,
                                      torch::Tensor rotations, torch::Tensor opacity_logits,
                                      torch::Tensor sh_dc, torch::Tensor sh_rest, torch::Tensor turn,
                                      torch::Tensor cam, int64_t width, int64_t height,
                                      int64_t deg, double scale_modifier, bool want_color,
                                      int64_t num_threads) {
  positions = positions.contiguous(); log_scales = log_scales.contiguous();
  rotations = rotations.contiguous(); opacity_logits = opacity_logits.contiguous();
  sh_dc = sh_dc.contiguous(); sh_rest = sh_rest.contiguous(); cam = cam.contiguous();
  TORCH_CHECK(cam.dtype() == torch::kFloat64 && cam.numel() == 16, "cam: 16 float64 expected");
  const int64_t N = positions.size(0);
  const int64_t K = sh_rest.dim() == 3 ? sh_rest.size(1) : 0;
  TORCH_CHECK((deg + 1) * (deg + 1) - 1 <= K, "sh_rest too small for the SH degree");
  const double* cm = cam.data_ptr<double>();
  const double fx = cm[12], fy = cm[13], cx = cm[14], cy = cm[15];
  const int W = static_cast<int>(width), H = static_cast<int>(height);
  const int gx = (W + BLOCK - 1) / BLOCK, gy = (H + BLOCK - 1) / BLOCK;
  const float Rf[9] = {(float)cm[0], (float)cm[1], (float)cm[2], (float)cm[3], (float)cm[4],
                       (float)cm[5], (float)cm[6], (float)cm[7], (float)cm[8]};
  float campos[3];
  camera_centre(cm, campos);
  const float limx = (float)(1.3 * (W / (2.0 * fx))), limy = (float)(1.3 * (H / (2.0 * fy)));
  const float ffx = (float)fx, ffy = (float)fy, smod = (float)scale_modifier;
  TORCH_CHECK(W > 0 && H > 0 && W <= 32767 && H <= 32767, "image size out of range (1..32767)");
  TORCH_CHECK(N < (int64_t(1) << 31), "too many Gaussians");

  auto means = torch::empty({N, 2}, torch::kFloat32);
  auto conic = torch::empty({N, 3}, torch::kFloat32);
  auto opac = torch::empty({N}, torch::kFloat32);
  auto colors = torch::zeros({N, 3}, torch::kFloat32);
  auto boxes = torch::zeros({N, 4}, torch::kInt16);
  auto depth = torch::zeros({N}, torch::kFloat32);   // > 0.2 for a visible row, 0 for a culled one
  const float* P = positions.data_ptr<float>();
  const float* S = log_scales.data_ptr<float>();
  const float* Q = rotations.data_ptr<float>();
  const float* O = opacity_logits.data_ptr<float>();
  const float* DC = sh_dc.data_ptr<float>();
  const float* REST = K ? sh_rest.data_ptr<float>() : nullptr;
  const float* TURN = colour_turn(turn);
  float* mp = means.data_ptr<float>(); float* cp = conic.data_ptr<float>();
  float* op = opac.data_ptr<float>(); float* colp = colors.data_ptr<float>();
  int16_t* bp = boxes.data_ptr<int16_t>();
  float* dp = depth.data_ptr<float>();

  parallel_chunks(N, num_threads, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const double px = P[3 * i], py = P[3 * i + 1], pz = P[3 * i + 2];
      const double vx = cm[0] * px + cm[1] * py + cm[2] * pz + cm[9];
      const double vy = cm[3] * px + cm[4] * py + cm[5] * pz + cm[10];
      const double vz = cm[6] * px + cm[7] * py + cm[8] * pz + cm[11];
      if (!(vz > 0.2)) continue;
      const float tx = (float)vx, ty = (float)vy, tz = (float)vz;
      // 3D covariance from the normalised quaternion and exp(log-scale) * modifier.
      float qr = Q[4 * i], qx = Q[4 * i + 1], qy = Q[4 * i + 2], qz = Q[4 * i + 3];
      const float qn = std::sqrt(qr * qr + qx * qx + qy * qy + qz * qz);
      qr /= qn; qx /= qn; qy /= qn; qz /= qn;
      const float Rq[9] = {1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qr * qz), 2 * (qx * qz + qr * qy),
                           2 * (qx * qy + qr * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qr * qx),
                           2 * (qx * qz - qr * qy), 2 * (qy * qz + qr * qx), 1 - 2 * (qx * qx + qy * qy)};
      const float s[3] = {std::exp(S[3 * i]) * smod, std::exp(S[3 * i + 1]) * smod,
                          std::exp(S[3 * i + 2]) * smod};
      float Ms[9];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) Ms[3 * r + c] = Rq[3 * r + c] * s[c];
      float sig[9];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          sig[3 * r + c] = Ms[3 * r] * Ms[3 * c] + Ms[3 * r + 1] * Ms[3 * c + 1] + Ms[3 * r + 2] * Ms[3 * c + 2];
      // EWA with the clamped perspective Jacobian, T = J W.
      const float txc = std::min(limx, std::max(-limx, tx / tz)) * tz;
      const float tyc = std::min(limy, std::max(-limy, ty / tz)) * tz;
      const float J[6] = {ffx / tz, 0.0f, -(ffx * txc) / (tz * tz), 0.0f, ffy / tz, -(ffy * tyc) / (tz * tz)};
      float T[6];
      for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 3; ++c)
          T[3 * r + c] = J[3 * r] * Rf[c] + J[3 * r + 1] * Rf[3 + c] + J[3 * r + 2] * Rf[6 + c];
      float TS[6];
      for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 3; ++c)
          TS[3 * r + c] = T[3 * r] * sig[c] + T[3 * r + 1] * sig[3 + c] + T[3 * r + 2] * sig[6 + c];
      const float c00 = TS[0] * T[0] + TS[1] * T[1] + TS[2] * T[2];
      const float c01 = TS[0] * T[3] + TS[1] * T[4] + TS[2] * T[5];
      const float c11 = TS[3] * T[3] + TS[4] * T[4] + TS[5] * T[5];
      const float a = c00 + 0.3f, b = c01, c = c11 + 0.3f;
      const float det = a * c - b * b;
      if (det == 0.0f) continue;
      const float det_inv = 1.0f / det;
      const float ca = c * det_inv, cb = -b * det_inv, cc = a * det_inv;
      const float mid = 0.5f * (a + c);
      const float lam1 = mid + std::sqrt(std::max(mid * mid - det, 0.1f));
      const float radius = std::ceil(3.0f * std::sqrt(lam1));
      const float mx = (float)(fx * vx / vz + (cx - 0.5)), my = (float)(fy * vy / vz + (cy - 0.5));
      auto clampi = [](float v, int hi) {
        const int64_t k = (int64_t)v;  // truncation towards zero, as graphdeco's (int) cast
        return (int)std::min<int64_t>(hi, std::max<int64_t>(0, k));
      };
      const int x0 = clampi((mx - radius) / BLOCK, gx), y0 = clampi((my - radius) / BLOCK, gy);
      const int x1 = clampi((mx + radius + (BLOCK - 1)) / BLOCK, gx);
      const int y1 = clampi((my + radius + (BLOCK - 1)) / BLOCK, gy);
      if (!(radius > 0) || (int64_t)(x1 - x0) * (y1 - y0) <= 0) continue;
      dp[i] = tz;
      mp[2 * i] = mx; mp[2 * i + 1] = my;
      cp[3 * i] = ca; cp[3 * i + 1] = cb; cp[3 * i + 2] = cc;
      const float o = 1.0f / (1.0f + std::exp(-O[i]));
      op[i] = o;
      // Conservative box of the alpha >= 1/255 region, in double. alpha >= 1/255 needs
      // o exp(power) >= 1/255, i.e. q(d) = d^T Q d <= 2 ln(255 o) =: 2L. The ellipse q <= 2L'
      // has half-widths sqrt(2L' Q_c / det Q), sqrt(2L' Q_a / det Q). L' adds a margin for the
      // float32 evaluation of q (its rounding error is a few ulps of the largest term, and each
      // term is <= 2L kappa with kappa = Q_a Q_c / det Q >= 1), then one more pixel is added.
      // Non-positive-definite conics get the whole image (no shortcut); o < 1/255 never draws.
      {
        const double qa = ca, qb = cb, qc = cc, od = o;
        const double detq = qa * qc - qb * qb;
        int32_t bx[4];
        if (255.0 * od < 1.0 - 1e-4) {
          bx[0] = bx[1] = bx[2] = bx[3] = 0;
        } else {
          const bool pd = detq > 0 && qa > 0 && qc > 0 && std::isfinite(detq);
          const double L = std::max(std::log(std::max(255.0 * od, 1e-30)), 0.0);
          const double kappa = pd ? qa * qc / detq : 1.0;
          const double Lm = L + 1e-6 * kappa * (L + 1.0) + 1e-4;
          const double hx = std::sqrt(2.0 * Lm * (pd ? qc : 0.0) / (pd ? detq : 1.0)) + 1.0;
          const double hy = std::sqrt(2.0 * Lm * (pd ? qa : 0.0) / (pd ? detq : 1.0)) + 1.0;
          if (!pd || !std::isfinite(hx) || !std::isfinite(hy) || !std::isfinite((double)mx) ||
              !std::isfinite((double)my)) {
            bx[0] = 0; bx[1] = 0; bx[2] = W; bx[3] = H;
          } else {
            auto cl = [](double v, int hi) { return (int32_t)std::min<double>(hi, std::max<double>(0, v)); };
            bx[0] = cl(std::ceil(mx - hx), W); bx[2] = cl(std::floor(mx + hx) + 1, W);
            bx[1] = cl(std::ceil(my - hy), H); bx[3] = cl(std::floor(my + hy) + 1, H);
          }
        }
        // Cut to the pixels of the graphdeco tile rectangle: rasterize then bins into the
        // rectangle's tiles that meet the box and visits, in each, the pixels of the box -- what
        // it did with the rectangle and the box apart (no [N, 4] rectangle array).
        bx[0] = std::max(bx[0], x0 * BLOCK); bx[2] = std::min(bx[2], x1 * BLOCK);
        bx[1] = std::max(bx[1], y0 * BLOCK); bx[3] = std::min(bx[3], y1 * BLOCK);
        if (bx[2] <= bx[0] || bx[3] <= bx[1]) bx[0] = bx[1] = bx[2] = bx[3] = 0;
        for (int k = 0; k < 4; ++k) bp[4 * i + k] = static_cast<int16_t>(bx[k]);  // <= W, H
      }
      if (want_color)
        sh_color(P + 3 * i, DC + 3 * i, REST ? REST + 3 * K * i : nullptr, deg, campos, TURN, colp + 3 * i);
    }
  });
  // Front-to-back order of the visible Gaussians; stable so equal depths keep index order.
  // Depths are > 0.2, so their IEEE bit patterns sort like the numbers: an LSD radix sort of
  // the bits (11, 11, 10 per pass; stable), fed in index order, gives ties in index order --
  // the order a sort of (bits, index) keys gives, in linear time (the comparison sort was a
  // third of this function on one thread).
  int64_t count = 0;
  for (int64_t i = 0; i < N; ++i) count += dp[i] > 0.0f;
  auto order = torch::empty({count}, torch::kInt32);
  {
    std::vector<uint32_t> ka(count), kb(count);
    std::vector<int32_t> va(count);
    int32_t* vb = order.data_ptr<int32_t>();
    for (int64_t i = 0, j = 0; i < N; ++i) {
      if (!(dp[i] > 0.0f)) continue;
      std::memcpy(&ka[j], dp + i, sizeof(uint32_t));
      va[j++] = static_cast<int32_t>(i);
    }
    depth = torch::Tensor();
    constexpr int SHIFT[3] = {0, 11, 22};
    constexpr uint32_t MASK[3] = {0x7ffu, 0x7ffu, 0x3ffu};
    std::vector<int64_t> hist(3 * 2048, 0);
    for (int64_t j = 0; j < count; ++j)
      for (int p = 0; p < 3; ++p) hist[p * 2048 + ((ka[j] >> SHIFT[p]) & MASK[p])]++;
    uint32_t* ks = ka.data(); uint32_t* kd = kb.data();
    int32_t* vs = va.data(); int32_t* vd = vb;
    for (int p = 0; p < 3; ++p) {
      int64_t* h = hist.data() + p * 2048;
      if (count == 0 || h[(ks[0] >> SHIFT[p]) & MASK[p]] == count) continue;  // one digit: as is
      int64_t at = 0;
      for (int d = 0; d < 2048; ++d) { const int64_t c = h[d]; h[d] = at; at += c; }
      for (int64_t j = 0; j < count; ++j) {
        const int64_t k = h[(ks[j] >> SHIFT[p]) & MASK[p]]++;
        kd[k] = ks[j];
        vd[k] = vs[j];
      }
      std::swap(ks, kd);
      std::swap(vs, vd);
    }
    if (vs != vb) std::memcpy(vb, vs, sizeof(int32_t) * count);
  }
  return {means, conic, opac, colors, boxes, order};
}

// The colours preprocess computes (want_color), of every row of a row range: positions [n,3],
// sh_dc [n,3], sh_rest [n,K,3], turn and cam as preprocess's -> out [n,3] f32 (contiguous, written in
// place). A caller whose SH rest is made a row range at a time (render.py) fills preprocess's
// colours with it; rows preprocess culls are never read by rasterize.
void sh_colors(torch::Tensor positions, torch::Tensor sh_dc, torch::Tensor sh_rest, torch::Tensor turn,
               torch::Tensor cam, int64_t deg, torch::Tensor out, int64_t num_threads) {
  positions = positions.contiguous(); sh_dc = sh_dc.contiguous(); sh_rest = sh_rest.contiguous();
  cam = cam.contiguous();
  TORCH_CHECK(cam.dtype() == torch::kFloat64 && cam.numel() == 16, "cam: 16 float64 expected");
  TORCH_CHECK(out.dtype() == torch::kFloat32 && out.is_contiguous(), "out: contiguous float32 expected");
  const int64_t n = positions.size(0);
  const int64_t K = sh_rest.dim() == 3 ? sh_rest.size(1) : 0;
  TORCH_CHECK((deg + 1) * (deg + 1) - 1 <= K, "sh_rest too small for the SH degree");
  TORCH_CHECK(sh_dc.size(0) == n && (K == 0 || sh_rest.size(0) == n) && out.size(0) == n,
              "row counts differ");
  float campos[3];
  camera_centre(cam.data_ptr<double>(), campos);
  const float* P = positions.data_ptr<float>();
  const float* DC = sh_dc.data_ptr<float>();
  const float* REST = K ? sh_rest.data_ptr<float>() : nullptr;
  const float* TURN = colour_turn(turn);
  float* colp = out.data_ptr<float>();
  parallel_chunks(n, num_threads, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i)
      sh_color(P + 3 * i, DC + 3 * i, REST ? REST + 3 * K * i : nullptr, deg, campos, TURN, colp + 3 * i);
  });
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  // Both run without the GIL (they touch no Python object; libtorch allocates without it), so
  // a Python thread -- the size search trains SH codebooks on one -- keeps running meanwhile.
  m.def("preprocess", &preprocess, "gsz CPU 3DGS per-Gaussian preprocessing",
        py::call_guard<py::gil_scoped_release>());
  m.def("rasterize", &rasterize, "gsz CPU 3DGS tile rasteriser (forward + importance)",
        py::call_guard<py::gil_scoped_release>());
  m.def("sh_colors", &sh_colors, "gsz CPU 3DGS SH colours of a row range",
        py::call_guard<py::gil_scoped_release>());
}
