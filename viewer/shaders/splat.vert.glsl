#version 430
// One instanced quad per splat, drawn back to front in the order of the `order` buffer.
// The quad (centre + x A + y B, x, y in [-1, 1]) was chosen by preprocess.comp.glsl: the
// oriented bounding rectangle of the alpha >= 1/255 ellipse or the splat's pixel box; the
// fragment shader clips it to the pixel box (graphdeco's tile rectangle) and applies the
// exact alpha cut-off.  This shader only fetches: on a software GL it runs single-threaded.
layout(std430, binding = 2) readonly buffer Projected { vec4 projected[]; };
layout(std430, binding = 3) readonly buffer Order { uint order[]; };

uniform vec2 u_size;   // viewport width, height in pixels

flat out vec2 v_mean;
flat out vec3 v_conic;
flat out vec4 v_color;  // rgb, opacity
flat out vec4 v_box;    // pixel box lo.xy, hi.xy (inclusive, graphdeco pixel coordinates)

void main() {
    uint i = order[gl_InstanceID];
    vec4 p0 = projected[4u * i];
    if (p0.w == 0.0) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }  // culled: degenerate
    vec4 p1 = projected[4u * i + 1u];
    vec4 p2 = projected[4u * i + 2u];
    vec4 p3 = projected[4u * i + 3u];
    uint lo = floatBitsToUint(p2.z), hi = floatBitsToUint(p2.w);
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec2 A = p3.zw;
    vec2 B = p0.w * vec2(-A.y, A.x);
    // + 0.5: graphdeco pixel coordinates (centres at integers) -> framebuffer pixels
    vec2 px = p3.xy + corner.x * A + corner.y * B + 0.5;
    // Row 0 of the image is the top row: flip y into GL's bottom-left clip space.
    gl_Position = vec4(px.x / u_size.x * 2.0 - 1.0, 1.0 - px.y / u_size.y * 2.0, 0.0, 1.0);
    v_mean = p0.xy;
    v_conic = p1.xyz;
    v_color = vec4(p1.w, p2.x, p2.y, p0.z);
    v_box = vec4(float(lo & 0xffffu), float(lo >> 16), float(hi & 0xffffu), float(hi >> 16));
}
