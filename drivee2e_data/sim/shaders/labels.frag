#version 330
// Labels only (the depth-image LiDAR, masks): body id and depth, no shading.
// Uniforms: none.
in float eye_depth;
flat in float body;
layout(location = 0) out vec4 rgba;
layout(location = 1) out float body_out;
layout(location = 2) out float depth_out;
void main() {
    rgba = vec4(0.0, 0.0, 0.0, 1.0);
    body_out = body;
    depth_out = eye_depth;
}
