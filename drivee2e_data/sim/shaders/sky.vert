#version 330
// The sky: one triangle covering the screen, each pixel's view direction from the inverse
// view-projection.
// Uniforms: inverse_view_projection (clip space to world, without the camera's translation).
uniform mat4 inverse_view_projection;
in vec2 in_corner;
out vec3 direction;
void main() {
    gl_Position = vec4(in_corner, 1.0, 1.0);  // on the far plane: drawn where nothing else is
    vec4 far_point = inverse_view_projection * vec4(in_corner, 1.0, 1.0);
    direction = far_point.xyz / far_point.w;
}
