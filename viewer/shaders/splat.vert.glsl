#version 430
// One instanced quad per splat, drawn back to front in the order of the `order` buffer; the
// quad covers exactly the pixels of the splat's box computed by preprocess.comp.glsl.
layout(std430, binding = 2) readonly buffer Projected { vec4 projected[]; };
layout(std430, binding = 3) readonly buffer Order { uint order[]; };

uniform vec2 u_size;   // viewport width, height in pixels

flat out vec2 v_mean;
flat out vec3 v_conic;
flat out vec4 v_color;  // rgb, opacity

void main() {
    uint i = order[gl_InstanceID];
    vec4 p0 = projected[3u * i];
    vec4 p1 = projected[3u * i + 1u];
    vec4 p2 = projected[3u * i + 2u];
    if (p0.w == 0.0) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }  // culled: degenerate
    uint lo = floatBitsToUint(p2.z), hi = floatBitsToUint(p2.w);
    // Pixel (ix, iy) covers [ix - 0.5, ix + 0.5] in graphdeco coordinates (centres at integers).
    vec2 lo_px = vec2(float(lo & 0xffffu), float(lo >> 16)) - 0.5;
    vec2 hi_px = vec2(float(hi & 0xffffu), float(hi >> 16)) + 0.5;
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));
    vec2 px = mix(lo_px, hi_px, corner) + 0.5;          // framebuffer pixels, top-left origin
    // Row 0 of the image is the top row: flip y into GL's bottom-left clip space.
    gl_Position = vec4(px.x / u_size.x * 2.0 - 1.0, 1.0 - px.y / u_size.y * 2.0, 0.0, 1.0);
    v_mean = p0.xy;
    v_conic = p1.xyz;
    v_color = vec4(p1.w, p2.x, p2.y, p0.z);
}
