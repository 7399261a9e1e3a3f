#version 430
// Per-splat preprocessing, one invocation per Gaussian: the EWA projection, SH colour and
// screen rectangle of graphdeco's diff-gaussian-rasterization forward pass, step by step as
// gsz.evaluation.render (the CPU reference) does it.  Writes 4 vec4 per splat:
//   out0 = (mean_x, mean_y, opacity, ratio)      graphdeco pixel coordinates (centres at ints)
//   out1 = (conic_a, conic_b, conic_c, colour_r) conic = inverse of the dilated 2D covariance
//   out2 = (colour_g, colour_b, lo, hi)          pixel box (inclusive), 2 x 16-bit ints each
//   out3 = (centre_x, centre_y, A_x, A_y)        quad = centre + x A + y ratio perp(A)
// An invalid splat (behind the near plane, det == 0, empty tile rectangle, or opacity
// < 1/255) has ratio = 0 and is skipped by the vertex shader.
layout(local_size_x = 256) in;

struct Splat { vec4 pos_op; vec4 scale; vec4 rot; vec4 dc; };
// Bindings 0 and 1 are RANGES starting at splat u_base (index them with the local index);
// binding 2 is the whole projected buffer (global index).
layout(std430, binding = 0) readonly buffer Splats { Splat splats[]; };
layout(std430, binding = 1) readonly buffer ShRest { float sh_rest[]; };   // [n, K, 3] chunk
layout(std430, binding = 2) writeonly buffer Projected { vec4 projected[]; };

uniform uint u_base;          // first splat of this dispatch (sh_rest is bound from here)
uniform uint u_count;         // splats in this dispatch
uniform uint u_k;             // SH rest coefficients per channel stored per splat (0, 3, 8, 15)
uniform int u_degree;         // SH degree to evaluate (<= degree of the stored coefficients)
uniform mat3 u_R;             // world -> camera rotation (column-major as GLSL wants)
uniform vec3 u_t;             // world -> camera translation
uniform vec3 u_campos;        // camera centre in world space
uniform vec4 u_intr;          // fx, fy, cx - 0.5, cy - 0.5
uniform vec2 u_size;          // width, height in pixels
uniform float u_scale_mod;    // splat-scale slider (graphdeco scaling_modifier)

const float NEAR = 0.2;
const float DILATION = 0.3;
const float BLOCK = 16.0;
const float C0 = 0.28209479177387814;
const float C1 = 0.4886025119029199;
const float C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                             -1.0925484305920792, 0.5462742152960396);
const float C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                             0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                             -0.5900435899266435);

vec3 rest(uint local, uint k) {
    uint b = (local * u_k + k) * 3u;
    return vec3(sh_rest[b], sh_rest[b + 1u], sh_rest[b + 2u]);
}

vec3 eval_sh(uint local, vec3 dc, vec3 d) {
    vec3 r = C0 * dc;
    if (u_degree > 0) {
        float x = d.x, y = d.y, z = d.z;
        r = r - C1 * y * rest(local, 0u) + C1 * z * rest(local, 1u) - C1 * x * rest(local, 2u);
        if (u_degree > 1) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            r = r + C2[0] * xy * rest(local, 3u) + C2[1] * yz * rest(local, 4u)
                  + C2[2] * (2.0 * zz - xx - yy) * rest(local, 5u)
                  + C2[3] * xz * rest(local, 6u) + C2[4] * (xx - yy) * rest(local, 7u);
            if (u_degree > 2) {
                r = r + C3[0] * y * (3.0 * xx - yy) * rest(local, 8u)
                      + C3[1] * xy * z * rest(local, 9u)
                      + C3[2] * y * (4.0 * zz - xx - yy) * rest(local, 10u)
                      + C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * rest(local, 11u)
                      + C3[4] * x * (4.0 * zz - xx - yy) * rest(local, 12u)
                      + C3[5] * z * (xx - yy) * rest(local, 13u)
                      + C3[6] * x * (xx - 3.0 * yy) * rest(local, 14u);
            }
        }
    }
    return r;
}

void invalid(uint i) {
    projected[4u * i] = vec4(0.0);   // .w = 0 marks the splat as not drawn
}

void main() {
    uint local = gl_GlobalInvocationID.x;
    if (local >= u_count) return;
    uint i = u_base + local;
    Splat s = splats[local];
    vec3 p = s.pos_op.xyz;
    vec3 v = u_R * p + u_t;
    if (!(v.z > NEAR)) { invalid(i); return; }
    float tx = v.x, ty = v.y, tz = v.z;

    // 3D covariance Sigma = M M^T with M = R(q) diag(exp(log_scale) * modifier).
    vec4 q = s.rot / length(s.rot);
    float qr = q.x, qx = q.y, qy = q.z, qz = q.w;
    mat3 Rq = transpose(mat3(
        1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qr * qz), 2.0 * (qx * qz + qr * qy),
        2.0 * (qx * qy + qr * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qr * qx),
        2.0 * (qx * qz - qr * qy), 2.0 * (qy * qz + qr * qx), 1.0 - 2.0 * (qx * qx + qy * qy)));
    vec3 sc = exp(s.scale.xyz) * u_scale_mod;
    mat3 M = Rq * mat3(sc.x, 0.0, 0.0, 0.0, sc.y, 0.0, 0.0, 0.0, sc.z);
    mat3 Sigma = M * transpose(M);

    // EWA with the perspective Jacobian at the centre, x/z and y/z clamped to 1.3 tan(fov/2).
    float fx = u_intr.x, fy = u_intr.y;
    float limx = 1.3 * (u_size.x / (2.0 * fx));
    float limy = 1.3 * (u_size.y / (2.0 * fy));
    float txc = clamp(tx / tz, -limx, limx) * tz;
    float tyc = clamp(ty / tz, -limy, limy) * tz;
    // J is 2x3; embed it as the first two rows of a mat3 (GLSL matrices are column-major).
    mat3 J = mat3(fx / tz, 0.0, 0.0,
                  0.0, fy / tz, 0.0,
                  -(fx * txc) / (tz * tz), -(fy * tyc) / (tz * tz), 0.0);
    mat3 T = J * u_R;
    mat3 cov = T * Sigma * transpose(T);
    float a = cov[0][0] + DILATION;
    float b = cov[1][0];
    float c = cov[1][1] + DILATION;
    float det = a * c - b * b;
    if (det == 0.0) { invalid(i); return; }
    float det_inv = 1.0 / det;
    vec3 conic = vec3(c * det_inv, -b * det_inv, a * det_inv);
    float mid = 0.5 * (a + c);
    float lam1 = mid + sqrt(max(mid * mid - det, 0.1));
    float radius = ceil(3.0 * sqrt(lam1));
    vec2 mean = vec2(fx * tx / tz + u_intr.z, fy * ty / tz + u_intr.w);

    // graphdeco getRect in tiles (int casts truncate towards zero), clamped to the grid.
    vec2 grid = floor((u_size + (BLOCK - 1.0)) / BLOCK);
    vec2 r0 = clamp(trunc((mean - radius) / BLOCK), vec2(0.0), grid);
    vec2 r1 = clamp(trunc((mean + radius + (BLOCK - 1.0)) / BLOCK), vec2(0.0), grid);
    if (!(radius > 0.0) || (r1.x - r0.x) * (r1.y - r0.y) <= 0.0) { invalid(i); return; }
    float opacity = 1.0 / (1.0 + exp(-s.pos_op.w));
    if (255.0 * opacity < 1.0 - 1e-4) { invalid(i); return; }

    // Pixel box: the tile rectangle (in pixels) cut down to a conservative box of the
    // alpha >= 1/255 ellipse d^T conic d <= 2 ln(255 opacity) (+1 px margin); the fragment
    // shader applies the exact cut-off.  Pixels are integer graphdeco coordinates.
    vec2 lo = r0 * BLOCK, hi = min(r1 * BLOCK, u_size) - 1.0;
    float L = max(log(255.0 * opacity), 0.0) + 1e-3;
    float detq = conic.x * conic.z - conic.y * conic.y;
    if (detq > 0.0 && conic.x > 0.0 && conic.z > 0.0) {
        vec2 h = sqrt(2.0 * L * vec2(conic.z, conic.x) / detq) + 1.0;
        lo = max(lo, ceil(mean - h));
        hi = min(hi, floor(mean + h));
    }
    if (hi.x < lo.x || hi.y < lo.y) { invalid(i); return; }

    // The quad to rasterise, as centre + x A + y B for x, y in [-1, 1]: the ORIENTED bounding
    // rectangle of the alpha >= 1/255 ellipse (fewer pixels than an axis-aligned box for thin
    // or rotated splats), or the pixel box itself when that is smaller (splats cut by their
    // tile rectangle or the screen).  Computed here, once per splat and in parallel, because a
    // software GL (llvmpipe) runs vertex shaders on a single thread.  B is perpendicular to A
    // and stored as the ratio |B| / |A|.
    vec2 qc = 0.5 * (lo + hi);
    vec2 A = vec2(0.5 * (hi.x - lo.x) + 0.5, 0.0);
    float ratio = (0.5 * (hi.y - lo.y) + 0.5) / A.x;
    if (detq > 0.0 && conic.x > 0.0) {
        // covariance (conic^-1) eigenvectors are the ellipse axes
        float sxx = a, syy = c, sxy = b;   // the dilated 2D covariance from above
        float hm = 0.5 * (sxx + syy);
        float rr = sqrt(max(0.25 * (sxx - syy) * (sxx - syy) + sxy * sxy, 0.0));
        float l1 = hm + rr, l2 = max(hm - rr, 0.0);
        vec2 e1 = abs(sxy) > 1e-12 * (abs(sxx) + abs(syy)) ? normalize(vec2(sxy, l1 - sxx))
                : (sxx >= syy ? vec2(1.0, 0.0) : vec2(0.0, 1.0));
        // +0.25 px: slack for float rounding at the rim (the fragment test is exact)
        vec2 h = vec2(sqrt(2.0 * L * l1), sqrt(2.0 * L * l2)) + 0.25;
        if (4.0 * h.x * h.y < (hi.x - lo.x + 1.0) * (hi.y - lo.y + 1.0)) {
            qc = mean;
            A = h.x * e1;
            ratio = h.y / h.x;
        }
    }

    vec3 dir = normalize(p - u_campos);
    vec3 col = max(eval_sh(local, s.dc.xyz, dir) + 0.5, 0.0);
    projected[4u * i] = vec4(mean, opacity, ratio);
    projected[4u * i + 1u] = vec4(conic, col.r);
    projected[4u * i + 2u] = vec4(col.g, col.b,
                                  uintBitsToFloat(uint(lo.x) | (uint(lo.y) << 16)),
                                  uintBitsToFloat(uint(hi.x) | (uint(hi.y) << 16)));
    projected[4u * i + 3u] = vec4(qc, A);
}
