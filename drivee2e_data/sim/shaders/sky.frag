// The sky pass (common.glsl is prepended): gradient, clouds and sun, seen through the fog.
// Uniforms: fog_rgb, fog_density (per metre; 0 clear), far_m.
uniform vec3 fog_rgb;
uniform float fog_density;
uniform float far_m;
in vec3 direction;
layout(location = 0) out vec4 bgra;  // blue first, as scene.frag's
layout(location = 1) out float depth_out;
layout(location = 2) out float body_out;  // where the view reads ids
void main() {
    vec3 sky = sky_colour(direction);
    bgra = vec4(mix(fog_rgb, sky, exp(-fog_density * far_m)).bgr, 1.0);
    body_out = 0.0;
    depth_out = far_m;
}
