#version 430
// Gaussian falloff with graphdeco's cut-offs; premultiplied output for back-to-front
// "over" blending (ONE, ONE_MINUS_SRC_ALPHA), which composites like the reference's front-to-
// back loop: C = sum c_i a_i T_i + T * background.
flat in vec2 v_mean;
flat in vec3 v_conic;
flat in vec4 v_color;
flat in vec4 v_box;
uniform vec2 u_size;
out vec4 frag;

void main() {
    // graphdeco pixel coordinates of this fragment's centre (integers), y down.
    vec2 pix = vec2(gl_FragCoord.x - 0.5, u_size.y - gl_FragCoord.y - 0.5);
    // only the pixels of the splat's tile rectangle see it (graphdeco's binning)
    if (any(lessThan(pix, v_box.xy)) || any(greaterThan(pix, v_box.zw))) discard;
    vec2 d = v_mean - pix;
    float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;
    if (power > 0.0) discard;
    float alpha = min(0.99, v_color.a * exp(power));
    if (alpha < 1.0 / 255.0) discard;
    frag = vec4(v_color.rgb * alpha, alpha);
}
