#version 430
// Puts the float renders of scene A (original) and B (decoded) on screen:
//   u_mode 0: one scene full frame (u_show: 0 = A, 1 = B, 2 = error heat map)
//   u_mode 1: vertical split at u_split pixels (left A, right B, or the heat map when u_heat)
//   u_mode 2: side by side (each texture holds a half-width render of the same camera)
// The heat map is max over RGB of |clamp(A) - clamp(B)| scaled by 1 / u_full_scale, on
// gsz-eval's black -> red -> yellow -> white ramp (gsz.evaluation.evaluate.error_map).
uniform sampler2D u_a;
uniform sampler2D u_b;
uniform int u_mode;
uniform int u_show;
uniform bool u_heat;
uniform float u_split;
uniform vec2 u_size;
uniform float u_full_scale;
uniform vec3 u_line_color;
out vec4 frag;

vec3 heat(vec2 uv) {
    vec3 a = clamp(texture(u_a, uv).rgb, 0.0, 1.0);
    vec3 b = clamp(texture(u_b, uv).rgb, 0.0, 1.0);
    vec3 d = abs(a - b);
    float t = clamp(max(d.r, max(d.g, d.b)) / u_full_scale, 0.0, 1.0) * 3.0;
    return vec3(clamp(t, 0.0, 1.0), clamp(t - 1.0, 0.0, 1.0), clamp(t - 2.0, 0.0, 1.0));
}

void main() {
    vec2 px = gl_FragCoord.xy;
    vec2 uv = px / u_size;
    vec3 c;
    if (u_mode == 0) {
        c = u_show == 2 ? heat(uv) : (u_show == 1 ? texture(u_b, uv).rgb : texture(u_a, uv).rgb);
    } else if (u_mode == 1) {
        if (abs(px.x - u_split) < 1.0) { frag = vec4(u_line_color, 1.0); return; }
        c = px.x < u_split ? texture(u_a, uv).rgb : (u_heat ? heat(uv) : texture(u_b, uv).rgb);
    } else {
        float half_w = floor(u_size.x / 2.0);
        if (px.x < half_w) {
            c = texture(u_a, vec2(px.x / half_w, uv.y)).rgb;
        } else {
            vec2 uvb = vec2((px.x - half_w) / half_w, uv.y);
            c = u_heat ? heat(uvb) : texture(u_b, uvb).rgb;
        }
        if (abs(px.x - half_w) < 1.0) { frag = vec4(u_line_color, 1.0); return; }
    }
    frag = vec4(clamp(c, 0.0, 1.0), 1.0);
}
