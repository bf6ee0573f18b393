#version 330
// The sun's shadow map: depth only, seen from the sun.
// Uniforms: shadow_matrix (world to the shadow map's clip space).
uniform mat4 shadow_matrix;
in vec3 in_position;
void main() {
    gl_Position = shadow_matrix * vec4(in_position, 1.0);
}
