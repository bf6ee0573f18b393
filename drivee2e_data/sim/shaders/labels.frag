#version 330
// Labels only (the depth-image LiDAR, masks): depth and body id, no shading, no colour (the
// renderer's labels framebuffer has these two attachments alone).
// Uniforms: none.
in float eye_depth;
flat in float body;
layout(location = 0) out float depth_out;
layout(location = 1) out float body_out;
void main() {
    depth_out = eye_depth;
    body_out = body;
}
